"""Topology of a mesh: watertight, 2-manifold, oriented; combinatorial, on the face indices as given (coincident
but distinct vertices are NOT merged).

- ``boundary_edges`` / ``nonmanifold_edges``: undirected edges used by exactly one face / by more than two
  faces.
- ``oriented``: no directed edge is used twice (neighbouring faces agree on orientation).
- ``two_manifold``: no face repeats a vertex, no edge has more than two faces, and around every referenced
  vertex the faces form a single fan (edge-connected through that vertex). Boundaries are allowed.
- ``watertight``: two_manifold, oriented, at least one face and no boundary edge (a closed, consistently
  oriented 2-manifold).
- ``manifold3d_ok``: manifold3d accepts the mesh (``Manifold(Mesh(...)).status() == NoError``), the library's
  own closed-oriented-2-manifold check.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tetweave_codec.metrics.common import as_mesh, sorted_unique


def _manifold3d_ok(vertices: np.ndarray, faces: np.ndarray) -> bool:
    import manifold3d

    if len(faces) == 0:
        return False
    mesh = manifold3d.Mesh(
        vert_properties=np.ascontiguousarray(vertices, dtype=np.float32),
        tri_verts=np.ascontiguousarray(faces, dtype=np.uint32),
    )
    return manifold3d.Manifold(mesh).status() == manifold3d.Error.NoError


def topology(vertices: np.ndarray, faces: np.ndarray) -> dict[str, int | bool]:
    """Combinatorial topology of a mesh and manifold3d's verdict (definitions in the module docstring)."""
    v, f = as_mesh(vertices, faces)
    n_vertices = len(v)
    degenerate = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    # half-edges (face, local k): from f[k] to f[k+1]
    src = f.reshape(-1)
    dst = f[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    key = lo * n_vertices + hi
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    uniq, start, count = np.unique(key_sorted, return_index=True, return_counts=True)
    boundary_edges = int(np.sum(count == 1))
    nonmanifold_edges = int(np.sum(count > 2))
    directed = src * n_vertices + dst
    oriented = len(sorted_unique(directed)) == len(directed)

    # Vertex manifoldness: corners (3F nodes) of the same vertex are joined across every two-face edge; each
    # vertex is a single fan iff its corners form one connected component.
    two = start[count == 2]
    h1, h2 = order[two], order[two + 1]

    def corner(h: np.ndarray, vertex: np.ndarray) -> np.ndarray:
        face, k = h // 3, h % 3
        return np.where(src[h] == vertex, 3 * face + k, 3 * face + (k + 1) % 3)

    u, w = lo[h1], hi[h1]
    rows = np.concatenate([corner(h1, u), corner(h1, w)])
    cols = np.concatenate([corner(h2, u), corner(h2, w)])
    n_corners = 3 * len(f)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_corners, n_corners))
    n_components, _ = connected_components(graph, directed=False)
    n_used = len(sorted_unique(src))
    vertex_manifold = n_components == n_used

    two_manifold = bool(len(f) and not degenerate.any() and nonmanifold_edges == 0 and vertex_manifold)
    watertight = bool(two_manifold and oriented and boundary_edges == 0)
    return {
        "watertight": watertight,
        "two_manifold": two_manifold,
        "oriented": bool(oriented),
        "manifold3d_ok": _manifold3d_ok(v, f),
        "boundary_edges": boundary_edges,
        "nonmanifold_edges": nonmanifold_edges,
        "degenerate_faces": int(degenerate.sum()),
        "n_edges": int(len(uniq)),
    }
