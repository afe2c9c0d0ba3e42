"""Open holes in a closed decoded surface: the faces a `.tw` file's holes section names, and the checks that keep
the result a 2-manifold with boundary.

The faces are named by rank in a canonical order of the *extracted* surface (marching tets and hull caps, before
smoothing and subdivision) that does not depend on the order in which a Delaunay backend lists its tets: a
face's key is its three vertex indices sorted ascending, the vertices in the decoder's canonical order (active
edges by key ``min(i, j) * N + max(i, j)``, then hull-cap vertices by point index: formats/README.md, "Decoding"),
and faces are ranked by key, lexicographically. Removing a face removes every face Loop subdivision made of it
(the 4^L faces ``[i * 4^L, (i + 1) * 4^L)`` of the subdivided surface, geometry/subdivision.py's order).
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.errors import ContainerError


def face_ranks(faces: np.ndarray) -> np.ndarray:
    """Canonical rank (F,) int64 of each face of faces (F,3) (see the module docstring)."""
    f = np.sort(np.asarray(faces, dtype=np.int64).reshape(-1, 3), axis=1)
    order = np.lexsort((f[:, 2], f[:, 1], f[:, 0]))
    ranks = np.empty(len(f), dtype=np.int64)
    ranks[order] = np.arange(len(f))
    return ranks


def pinched_vertices(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """Vertices (P,) int64 whose faces form more than one fan (edge-connected around the vertex): where a surface
    with boundary stops being a 2-manifold. faces (F,3) of a surface whose edges have at most two faces."""
    # scipy.sparse costs ~0.25 s to import: only files with a holes section (and the encoder) pay it
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(f):
        return np.zeros(0, dtype=np.int64)
    corner = np.arange(3 * len(f)).reshape(-1, 3)  # corner (face, slot) -> node id
    # half-edge (a, b) of slot i joins the corners of a and b in its face with those of the opposite half-edge
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    ca = corner.reshape(-1)
    cb = np.roll(corner, -1, axis=1).reshape(-1)
    n = max(int(num_vertices), int(f.max()) + 1)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    sk = key[order]
    pair = np.flatnonzero(sk[1:] == sk[:-1])
    h1, h2 = order[pair], order[pair + 1]
    # h1 = (u, w), h2 = (w, u): corner of u in h1's face with corner of u in h2's face (h2's end), and w likewise
    rows = np.concatenate([ca[h1], cb[h1]])
    cols = np.concatenate([cb[h2], ca[h2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * len(f), 3 * len(f)))
    count, label = connected_components(graph, directed=False)
    fans = np.unique(a * np.int64(count) + label) // count  # one entry per (vertex, fan)
    counts = np.bincount(fans, minlength=n)
    return np.flatnonzero(counts > 1)


def without_pinches(faces: np.ndarray, remove: np.ndarray) -> np.ndarray:
    """remove (F,) bool, less every face around a vertex that removing them would pinch (two or more fans left),
    repeated until no vertex is pinched: a removal a decoder accepts. faces (F,3) of a closed 2-manifold."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    remove = np.asarray(remove, dtype=bool).copy()
    n = int(f.max()) + 1 if len(f) else 0
    while remove.any() and not remove.all():
        pinched = pinched_vertices(f[~remove], n)
        if not len(pinched):
            break
        remove &= ~np.isin(f, pinched).any(1)  # strictly fewer removed faces each time: at most F rounds
    return remove


def open_holes(
    vertices: np.ndarray, faces: np.ndarray, extracted_faces: np.ndarray, ranks: np.ndarray, children: int
) -> tuple[np.ndarray, np.ndarray]:
    """The decoder's last step for a file with a holes section.

    Args:
        vertices (V,3), faces (F,3): the closed surface after smoothing and subdivision.
        extracted_faces (F0,3): the surface the marching tets extracted (F = F0 * children).
        ranks (K,): strictly increasing canonical ranks of the extracted faces to remove.
        children: faces of `faces` per extracted face (4^L, or 1 when the filter left the surface unsubdivided).
    Returns:
        vertices (V',3) and faces (F',3): the faces kept, in their order, over the vertices they use (in order).
    Raises:
        ContainerError when a rank is not below F0 or the removal leaves a vertex with two or more fans (the
        result would not be a 2-manifold with boundary).
    """
    f0 = np.asarray(extracted_faces, dtype=np.int64).reshape(-1, 3)
    r = np.asarray(ranks, dtype=np.int64).reshape(-1)
    if len(f0) * children != len(faces):
        raise ValueError(f"{len(faces)} faces are not {children} per extracted face ({len(f0)})")
    if len(r) and r[-1] >= len(f0):
        raise ContainerError(f"invalid .tw file: hole face rank {int(r[-1])} but the surface has {len(f0)} faces")
    removed = np.zeros(len(f0), dtype=bool)  # by rank
    removed[r] = True
    by_face = removed[face_ranks(f0)]
    # A pinch of the subdivided result is a pinch of the extracted surface (Loop's new vertices are edge midpoints,
    # whose faces always form one fan; an old vertex's faces are its parents' children, joined the same way), so
    # the check runs on the 4^L times smaller surface.
    if len(pinched_vertices(f0[~by_face], int(f0.max()) + 1 if len(f0) else 0)):
        raise ContainerError("invalid .tw file: its holes leave a vertex where two parts of the surface meet")
    kept = np.asarray(faces, dtype=np.int64)[np.repeat(~by_face, children)]
    used = np.zeros(len(vertices), dtype=bool)
    used[kept.reshape(-1)] = True
    new_index = np.cumsum(used) - 1
    return np.asarray(vertices)[used], new_index[kept]
