"""Which faces of a decoded closed surface only cap the holes of an open input (the encoder's side of a `.tw`
holes section, formats/holes.py; the decoder's side is geometry/holes.py).

A TetWeave surface is closed, so where the input has a hole (a loop of boundary edges) the decoded surface spans
it. A face is a *cap* face when the point of the input nearest to its centroid lies on a boundary edge of the
input and is not the centroid itself: the face is off the input, beyond its rim; optionally the caps grow into
neighbours far from the input (a cap that sags into the shape). Removing them leaves the input's holes open; where
a vertex would be left with two fans, its whole fan goes too (a few rounds), and failing that its faces stay, so
the result is a 2-manifold with boundary. `packing.Packer.with_holes` picks between plain and grown caps by the
decoded mesh's Chamfer distance (docs/measurements/holes.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.holes import face_ranks, pinched_vertices, without_pinches

# A centroid at most this far from the input (normalized frame) lies on it, whatever its nearest feature.
ON_SURFACE = 1e-9
# The nearest point is on a boundary edge when it is within this distance of it (the query's rounding).
ON_EDGE = 1e-9
# A cap grows into its edge neighbours that lie farther from the input than this many times the mean distance of
# the other faces: a cap that sags into the shape (stanford-bunny 40 KB: 201 faces more than 0.01 from the input
# whose nearest input point is on an inner wall, not on the rim) is still a cap.
GROW_FACTOR = 8.0
# Rounds of widening a removal around the vertices it would pinch (`_widen`) before giving faces back.
WIDEN_ROUNDS = 8


@dataclass
class InputRim:
    """An open input prepared for cap queries: vertices (V,3) normalized frame, faces (F,3), boundary (F,3) bool
    whether side i (v_i, v_i+1) of each face is a boundary edge (one face only), tree over the input."""

    vertices: np.ndarray
    faces: np.ndarray
    boundary: np.ndarray
    tree: SurfaceTree


def input_rim(vertices: np.ndarray, faces: np.ndarray) -> InputRim | None:
    """The input's rim (see InputRim), or None when every edge has two or more faces (nothing to keep open).
    Vertices with equal coordinates are merged first: an OBJ's texture seams duplicate them, which would make
    every seam a rim (beast from common-3d-test-models: 3,280 seam edges, no hole)."""
    from tetweave_codec.fit.features import unique_rows, weld

    vertices, faces = weld(vertices, faces)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    half = np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)
    _, inverse, counts = unique_rows(np.sort(half, axis=1))
    boundary = (counts[inverse] == 1).reshape(-1, 3)
    if not boundary.any():
        return None
    v = np.asarray(vertices, dtype=np.float64)
    return InputRim(v, f, boundary, SurfaceTree(v, f))


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def cap_faces(rim: InputRim, vertices: np.ndarray, faces: np.ndarray, grow: bool = False) -> np.ndarray:
    """(F,) bool: the faces (F,3) over vertices (V,3) (normalized frame) that cap the input's holes: those whose
    centroid's nearest input point lies on a boundary edge; with `grow`, grown (`_grow`) into far neighbours."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(f):
        return np.zeros(0, dtype=bool)
    centroid = np.asarray(vertices, dtype=np.float64)[f].mean(1)
    sq, face, closest = rim.tree.query(centroid)
    distance = np.sqrt(np.maximum(sq, 0.0))
    cap = np.zeros(len(f), dtype=bool)
    off = np.flatnonzero((np.sqrt(np.maximum(sq, 0.0)) > ON_SURFACE) & rim.boundary[face].any(1))
    for side in range(3):
        sel = off[rim.boundary[face[off], side]]
        tri = rim.faces[face[sel]]
        a, b = rim.vertices[tri[:, side]], rim.vertices[tri[:, (side + 1) % 3]]
        cap[sel[_segment_distance(closest[sel], a, b) <= ON_EDGE]] = True
    return _grow(f, cap, distance) if grow else cap


def _grow(faces: np.ndarray, cap: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """cap (F,) grown through shared edges into faces whose centroid is more than GROW_FACTOR x the mean distance
    of the non-cap faces from the input (distance (F,)), until no face joins."""
    if not cap.any() or cap.all():
        return cap
    far = distance > GROW_FACTOR * float(distance[~cap].mean())
    half = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.sort(half, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    same = np.flatnonzero((key[order[1:]] == key[order[:-1]]).all(1))
    a, b = order[same] // 3, order[same + 1] // 3  # the two faces of each edge
    cap = cap.copy()
    while True:
        grow = np.zeros_like(cap)
        grow[b[cap[a] & ~cap[b] & far[b]]] = True
        grow[a[cap[b] & ~cap[a] & far[a]]] = True
        if not grow.any():
            return cap
        cap |= grow


def _widen(faces: np.ndarray, remove: np.ndarray) -> np.ndarray:
    """remove (F,) bool with every face around a vertex it would pinch removed too, for up to WIDEN_ROUNDS rounds.
    A pinch sits where two caps, or a cap and a stray far face, touch at a vertex; opening its whole fan keeps the
    cap open where giving its faces back (`geometry.holes.without_pinches`, still the last resort) closes part of
    it: bunny 40 KB Chamfer 2.38e-4 -> 2.33e-4, 10 KB 6.15e-4 -> 6.05e-4, 5 KB 1.085e-3 -> 1.073e-3 (same points)."""
    remove = remove.copy()
    n = int(faces.max()) + 1 if len(faces) else 0
    for _ in range(WIDEN_ROUNDS):
        if not remove.any() or remove.all():
            break
        pinched = pinched_vertices(faces[~remove], n)
        if not len(pinched):
            break
        remove |= np.isin(faces, pinched).any(1)
    return remove


def hole_ranks(rim: InputRim, vertices: np.ndarray, extracted_faces: np.ndarray, grow: bool = False) -> np.ndarray:
    """Sorted canonical ranks (K,) of the extracted faces to remove: the caps (`cap_faces`, grown with `grow`),
    widened around the vertices their removal would pinch (`_widen`), less the faces around any still pinched
    (repeated until none is). vertices: the closed surface (normalized frame) whose first vertices are the
    extracted surface's; extracted_faces (F0,3). Empty when nothing is to be removed or when the removal would
    leave no face."""
    f0 = np.asarray(extracted_faces, dtype=np.int64).reshape(-1, 3)
    cap = without_pinches(f0, _widen(f0, cap_faces(rim, vertices, f0, grow)))
    if not cap.any() or cap.all():
        return np.zeros(0, dtype=np.int64)
    return np.sort(face_ranks(f0)[cap])
