"""The share of a mesh's area that no outside view sees: the encoder's check of its decoded mesh against something
it did not fit to.

The encode summary's Chamfer distance measures the decoded mesh against the surface the fit took. When that
surface keeps strips inside the solid (parts that overlap or nest, with long faces: fit.visible splits a seam face
only so often), the decoded mesh keeps them too, as membranes and bubbles inside the solid, and the distance to
the same surface cannot see them. A viewer never sees them either: this module renders the decoded mesh itself
from VIEWS near-orthographic views (render.visibility, no culling: the renders the fit's visible surface takes of
its input) and sums the area of the faces that no view sees. A face counts as seen as `Renders.faces_seen` counts
it: it covers a pixel centre in some view, or its centroid lies within half a pixel of the plane of the face the
buffer holds there (faces smaller than a pixel). Decoded faces are about a pixel or smaller, so whole faces
measure the area closely.

On the clean decoded files of the four shared meshes (5-40 KB, 9k-320k faces) the share is at most 0.13 % (deep
crevices of stanford-bunny at 40 KB), 0.2-2.5 s; RESOLUTION 256 instead of the fit's 384 agrees within 0.01
percentage points there at ~0.7x the time (docs/measurements/self_check.md). Above WARN_SHARE the summary warns.

    share = unseen_area_share(vertices, faces)         # float in [0, 1], any frame
    check = self_check(vertices, faces)                # SelfCheck(share, seconds) | None, with the summary's lines
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from tetweave_codec.geometry.triangles import face_areas, face_normals

# The fit's views (render.visibility.VIEWS) at a lower resolution: the decoded mesh has no long faces to resolve, and
# 32 buffers at 384 px cost ~0.4 s even for a handful of faces. Meshes of few faces get fewer pixels, about one
# face per pixel across (sqrt(F) px, in steps of 32): the renders are most of a small mesh's cost (0.26 s at
# 256 px, 0.08 s at 128 px for 5k faces), and the faces of such a mesh cover pixel centres at the lower one.
VIEWS = 32
RESOLUTION = 256
MIN_RESOLUTION = 128
RESOLUTION_STEP = 32
# The summary warns above this share of the decoded area unseen (fit.visible.HIDDEN_AREA_SHARE's threshold: what
# "auto" counts as hidden on the input).
WARN_SHARE = 0.01


def resolution_for(n_faces: int) -> int:
    """Pixels across each view for a mesh of `n_faces` faces: sqrt(n_faces) rounded up to RESOLUTION_STEP, within
    [MIN_RESOLUTION, RESOLUTION]."""
    steps = math.ceil(math.sqrt(max(n_faces, 1)) / RESOLUTION_STEP)
    return int(min(RESOLUTION, max(MIN_RESOLUTION, steps * RESOLUTION_STEP)))


def unseen_faces(
    vertices: np.ndarray, faces: np.ndarray, views: int = VIEWS, resolution: int | None = None
) -> np.ndarray:
    """bool (F,): the faces (F,3) of the mesh (vertices (V,3), any frame) that no outside view sees, from `views`
    renders of `resolution` pixels across (default `resolution_for` the faces).

    The mesh is centred and scaled as the encoder normalizes an input (meshio.normalize), so the answer does not
    depend on its frame. InputError above render.visibility.MAX_FACES faces."""
    from tetweave_codec.meshio import normalize
    from tetweave_codec.render.visibility import MAX_FACES, render

    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return np.zeros(0, dtype=bool)
    if len(f) > MAX_FACES:
        from tetweave_codec.errors import InputError

        raise InputError(f"mesh: {len(f):,} faces are more than the {MAX_FACES:,} the self-check can render")
    # only the vertices faces use: unused ones neither widen the frame nor cost a projection
    used, inverse = np.unique(f, return_inverse=True)
    f = inverse.reshape(-1, 3)
    v, _, _ = normalize(np.asarray(vertices, dtype=np.float64)[used])
    renders = render(v, f, views, resolution or resolution_for(len(f)))
    seen = np.zeros(len(f), dtype=bool)
    ids = renders.face_id.reshape(-1)
    seen[ids[ids >= 0]] = True
    # Only faces that cover no pixel centre need the depth test of their centroid (Renders.faces_seen tests all).
    rest = np.flatnonzero(~seen)
    if len(rest):
        tri = f[rest]
        seen[rest] = renders.points_seen(v[tri].mean(axis=1), face_normals(v, tri)).any(axis=0)
    return ~seen


def unseen_area_share(
    vertices: np.ndarray, faces: np.ndarray, views: int = VIEWS, resolution: int | None = None
) -> float:
    """The share in [0, 1] of the mesh's area (vertices (V,3), faces (F,3), any frame) on faces that no outside
    view sees (`unseen_faces`); 0 for a mesh without area."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    area = face_areas(v, f) if len(f) else np.zeros(0)
    total = float(area.sum())
    if not np.isfinite(total) or total <= 0:
        return 0.0
    return float(area[unseen_faces(v, f, views, resolution)].sum() / total)


@dataclass(frozen=True)
class SelfCheck:
    """The encoder's self-check of a decoded mesh: share (in [0, 1]) of its area no outside view sees, and the
    seconds it took."""

    share: float
    seconds: float

    @property
    def warns(self) -> bool:
        return self.share > WARN_SHARE

    def line(self) -> str:
        """The encode summary's line."""
        return f"decoded area no outside view sees: {100 * self.share:.2f} % (self-check, {self.seconds:.1f}s)"

    def warning(self, surface: str | None) -> str | None:
        """The summary's warning when the share is above WARN_SHARE (None else); surface: what the fit took
        (stats["surface"]), which decides the advice."""
        if not self.warns:
            return None
        text = (
            f"warning: {100 * self.share:.1f} % of the decoded area lies inside the solid, where no outside view "
            "sees it: membranes or hidden parts were kept"
        )
        if surface == "visible":
            return text + " although the fit took the visible surface (parts that overlap with long faces)"
        return text + "; try --surface visible"


def self_check(vertices: np.ndarray, faces: np.ndarray) -> SelfCheck | None:
    """`unseen_area_share` of a decoded mesh (vertices (V,3) in any frame, faces (F,3)) with its time, or None when
    it is not measured (no faces, or more than render.visibility.MAX_FACES)."""
    from tetweave_codec.errors import InputError

    if len(faces) == 0:
        return None
    t0 = time.perf_counter()
    try:
        share = unseen_area_share(vertices, faces)
    except InputError:
        return None
    return SelfCheck(share, time.perf_counter() - t0)
