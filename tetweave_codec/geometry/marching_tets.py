"""Directional marching tetrahedra (TetWeave paper, section 3, eq. 1-2).

Inputs are a point cloud ``points (N, 3)``, positively oriented tets ``tets (T, 4)`` (see `delaunay`), the
base signed distance ``s (N,)`` (s < 0 inside; s >= 0 counts as outside) and optional SH coefficients
``c (N, q)``.

An edge (i, j) of a tet is *active* when its endpoints lie on different sides; orient it inside first,
s_i < 0 <= s_j. With the SH convention of `sh.py` (direction away from the point):

    s_hat_i = (1 + tanh(SH(dir(i -> j), c_i))) * s_i        s_hat_j = (1 + tanh(SH(dir(j -> i), c_j))) * s_j
    v = (s_hat_j * p_i - s_hat_i * p_j) / (s_hat_j - s_hat_i)

so s_hat keeps the sign of s and c = 0 gives the classic linear interpolation. Every unique active edge
carries exactly one output vertex, shared by all tets around the edge, so the output is watertight; triangles
come from `TRIANGLE_TABLE` (the standard marching-tets cases) and face outward (from s < 0 to s >= 0).
Orientation is derived from the tets' orientation, not from the geometry, so it is consistent even where tets
are flat.

Where the inside region reaches the convex hull of the points the surface would be open there; passing
``hull_faces`` (outward convex hull triangles, from `delaunay.tetrahedralize`) closes it with cap triangles
lying on the hull (as if everything beyond the hull were outside). Cap vertices sit at the inside hull points.

Two implementations share the tables and the vertex ordering (vertices sorted by edge key
``i_min * N + i_max``, faces by tet then table order, cap vertices/faces appended last):

* `marching_tets`: torch, differentiable w.r.t. points, s and c; topology under no_grad with 1-D int64 edge
  keys (torch.unique on keys; ``unique(dim=0)`` on edge pairs is 10-18x slower).
* `marching_tets_numpy`: numpy float64, no autograd; what the decoder uses (deterministic, no BLAS). Its integer
  topology (active edges, their order, faces) and `check_manifold` run in a compiled fast path
  (geometry/_mt_native.c, built by setup.py when a C compiler is there) with the same output; the numpy code here
  stays the reference and the fallback (extension absent, `NATIVE` False or TETWEAVE_NATIVE=0).

The output is a closed (with ``hull_faces``) 2-manifold only if the tets form a proper tetrahedralization (each
triangle shared by at most two tets, in opposite orientations; `delaunay` guarantees it). `marching_tets_numpy`
checks its own output -- every directed edge used once, and with ``hull_faces`` by exactly one opposite edge --
and raises `TopologyError` rather than return a broken mesh from a non-conforming input (one sort of 3F
integer keys).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from tetweave_codec.errors import TopologyError
from tetweave_codec.geometry.sh import degree_from_num_coeffs, sh_basis_terms, sh_parity
from tetweave_codec.geometry.tanh import tanh as decoder_tanh

if TYPE_CHECKING:  # torch is imported lazily: the numpy decoder path must not pay for it
    import torch

try:  # the compiled topology (optional; identical output)
    from tetweave_codec.geometry import _mt_native
except ImportError:  # not built: the numpy code below
    _mt_native = None
# Whether marching_tets_numpy and check_manifold use the compiled path. Measured: docs/measurements/decode_native.md.
NATIVE = _mt_native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"

# Local edges of a tet as pairs of local vertex indices: edge e connects TET_EDGES[e, 0] and TET_EDGES[e, 1].
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)

# Case code of a tet: sum over local vertices k of (s_k < 0) << k.
CASE_WEIGHTS = np.array([1, 2, 4, 8], dtype=np.int64)

# For each case code, up to two triangles given as local edge indices (-1: no triangle). Oriented outward for
# a positively oriented tet: the normal of (e0, e1, e2) points from the inside vertices to the outside ones.
TRIANGLE_TABLE = np.array(
    [
        [[-1, -1, -1], [-1, -1, -1]],  # 0 = 0000: all outside
        [[0, 1, 2], [-1, -1, -1]],  # 1 = 0001
        [[0, 4, 3], [-1, -1, -1]],  # 2 = 0010
        [[1, 2, 4], [1, 4, 3]],  # 3 = 0011
        [[1, 3, 5], [-1, -1, -1]],  # 4 = 0100
        [[3, 5, 2], [3, 2, 0]],  # 5 = 0101
        [[0, 4, 5], [0, 5, 1]],  # 6 = 0110
        [[2, 4, 5], [-1, -1, -1]],  # 7 = 0111
        [[2, 5, 4], [-1, -1, -1]],  # 8 = 1000
        [[0, 1, 5], [0, 5, 4]],  # 9 = 1001
        [[2, 5, 3], [2, 3, 0]],  # 10 = 1010
        [[1, 5, 3], [-1, -1, -1]],  # 11 = 1011
        [[1, 3, 4], [1, 4, 2]],  # 12 = 1100
        [[0, 3, 4], [-1, -1, -1]],  # 13 = 1101
        [[0, 2, 1], [-1, -1, -1]],  # 14 = 1110
        [[-1, -1, -1], [-1, -1, -1]],  # 15 = 1111: all inside
    ],
    dtype=np.int64,
)

# ACTIVE_EDGE_TABLE[code, e]: local edge e has endpoints on different sides in case `code`.
ACTIVE_EDGE_TABLE = ((np.arange(16)[:, None] >> TET_EDGES[:, 0]) & 1) != (
    (np.arange(16)[:, None] >> TET_EDGES[:, 1]) & 1
)

# ACTIVE_EDGE_TABLE as integers and the messages of check_manifold's three defects, shared with the compiled path.
_ACTIVE_INT = ACTIVE_EDGE_TABLE.astype(np.int64)
_MANIFOLD_ERRORS = (
    "marching tets produced a degenerate triangle: the tetrahedralization is not proper",
    "marching tets used a directed edge twice: the tetrahedralization is not proper",
    "marching tets left an edge without its twin: the tetrahedralization is not proper",
)

# Convex hull caps. A hull triangle (a, b, c) (outward) has 6 slots: 0-2 the cap vertices at a, b, c (if
# inside), 3-5 the edge vertices on (a, b), (b, c), (c, a). Case code: sum over k of (s_k < 0) << k. Triangles
# follow the hull triangle's own orientation, which is outward for the solid as well.
HULL_EDGES = np.array([[0, 1], [1, 2], [2, 0]], dtype=np.int64)
CAP_TABLE = np.array(
    [
        [[-1, -1, -1], [-1, -1, -1]],  # 0: nothing inside
        [[0, 3, 5], [-1, -1, -1]],  # 1: a
        [[1, 4, 3], [-1, -1, -1]],  # 2: b
        [[0, 1, 4], [0, 4, 5]],  # 3: a, b
        [[2, 5, 4], [-1, -1, -1]],  # 4: c
        [[2, 0, 3], [2, 3, 4]],  # 5: a, c
        [[1, 2, 5], [1, 5, 3]],  # 6: b, c
        [[0, 1, 2], [-1, -1, -1]],  # 7: a, b, c
    ],
    dtype=np.int64,
)


class MarchingTetsResult(NamedTuple):
    """Output of marching tets (torch tensors or numpy arrays, matching the input).

    vertices: (V, 3) surface vertices.
    faces: (F, 3) int64 triangles into `vertices`, oriented outward (s < 0 inside).
    edges: (V, 2) int64 active edge (i, j) of each vertex, s[i] < 0 <= s[j]; hull cap vertices (only with
        `hull_faces`) have (i, i) for the inside hull point i they sit on.
    face_tets: (F,) int64 index of the tet each face comes from; -1 for hull cap faces.
    """

    vertices: Any
    faces: Any
    edges: Any
    face_tets: Any


class Topology(NamedTuple):
    """The no-gradient part of `marching_tets` for one triangulation and one sign pattern (torch tensors).

    edges (V,2) long: active edge (i inside, j outside) of each surface vertex, cap vertices (i, i) last.
    faces (F,3) long, face_tets (F,) long (-1 for caps). num_edge_vertices: V minus the cap vertices.
    A fit's iterations between re-triangulations often keep every sign (77 % of them for spot at 8K points), and
    then all of this is the same; `marching_tets` takes it back instead of recomputing it.
    """

    edges: Any
    faces: Any
    face_tets: Any
    num_edge_vertices: int


def marching_tets(
    points: torch.Tensor,
    tets: torch.Tensor,
    s: torch.Tensor,
    c: torch.Tensor | None = None,
    hull_faces: torch.Tensor | None = None,
    topology: Topology | None = None,
) -> MarchingTetsResult:
    """Directional marching tets in torch, differentiable w.r.t. `points`, `s` and `c`.

    Args:
        points: (N, 3) float tensor.
        tets: (T, 4) long tensor, positively oriented.
        s: (N,) base signed distance, s < 0 inside.
        c: (N, q) SH coefficients, q in {0, 1, 4, 9, 16}, or None (same as q = 0: s_hat = s).
        hull_faces: optional (H, 3) long tensor, outward convex hull triangles; closes the surface there.
        topology: `marching_tets_topology(tets, s < 0, hull_faces)` when the caller has it (same tets, same
            signs); computed here otherwise.
    Returns:
        MarchingTetsResult of tensors on the device of `points`.
    """
    import torch

    if topology is None:
        with torch.no_grad():
            topology = marching_tets_topology(tets.to(points.device), s.detach() < 0, hull_faces)
    edges, k = topology.edges, topology.num_edge_vertices
    vertices = _edge_vertices(points, s, c, edges[:k, 0], edges[:k, 1])
    if k < edges.shape[0]:
        vertices = torch.cat([vertices, points[edges[k:, 0]]], 0)
    return MarchingTetsResult(vertices, topology.faces, edges, topology.face_tets)


def marching_tets_topology(tets: torch.Tensor, inside: torch.Tensor, hull_faces: torch.Tensor | None) -> Topology:
    """Active edges, faces and their tets for tets (T,4) long and the (N,) bool inside flags (s < 0); torch."""
    import torch

    device = inside.device
    n = inside.shape[0]
    tets = tets.to(device=device, dtype=torch.long)
    code = (inside[tets].long() * torch.as_tensor(CASE_WEIGHTS, device=device)).sum(1)
    tet_idx = torch.nonzero((code > 0) & (code < 15)).squeeze(1)
    code = code[tet_idx]
    ends = tets[tet_idx][:, torch.as_tensor(TET_EDGES, device=device)]  # (Tv, 6, 2)
    lo = torch.minimum(ends[..., 0], ends[..., 1])
    hi = torch.maximum(ends[..., 0], ends[..., 1])
    active = torch.as_tensor(ACTIVE_EDGE_TABLE, device=device)[code]  # (Tv, 6)
    keys, inverse = torch.unique((lo * n + hi)[active], sorted=True, return_inverse=True)
    slot = torch.full(active.shape, -1, dtype=torch.long, device=device)
    slot[active] = inverse
    tri = torch.as_tensor(TRIANGLE_TABLE, device=device)[code]  # (Tv, 2, 3)
    has = tri[..., 0] >= 0
    faces = torch.gather(slot, 1, tri.clamp(min=0).reshape(-1, 6)).reshape(-1, 2, 3)[has]
    face_tets = tet_idx[:, None].expand(-1, 2)[has]
    lo, hi = keys // n, keys % n
    lo_in = inside[lo]
    edges = torch.stack([torch.where(lo_in, lo, hi), torch.where(lo_in, hi, lo)], 1)
    num_edge_vertices = int(edges.shape[0])
    if hull_faces is not None and len(hull_faces):
        hull_faces = hull_faces.to(device=device, dtype=torch.long)
        cap = _caps_torch(hull_faces, inside, keys, n, num_edge_vertices)
        if cap is not None:
            cap_points, cap_faces = cap
            edges = torch.cat([edges, torch.stack([cap_points, cap_points], 1)], 0)
            faces = torch.cat([faces, cap_faces], 0)
            face_tets = torch.cat([face_tets, face_tets.new_full((cap_faces.shape[0],), -1)], 0)
    return Topology(edges, faces, face_tets, num_edge_vertices)


def _caps_torch(hull_faces, inside, keys, n, num_vertices):
    import torch

    device = hull_faces.device
    hin = inside[hull_faces]  # (H, 3)
    code = (hin.long() * torch.as_tensor(CASE_WEIGHTS[:3], device=device)).sum(1)
    sel = code > 0
    if not bool(sel.any()):
        return None
    hf, code, hin = hull_faces[sel], code[sel], hin[sel]
    cap_points = torch.unique(hf[hin])
    w_slot = num_vertices + torch.searchsorted(cap_points, hf).clamp(max=cap_points.shape[0] - 1)
    ends = hf[:, torch.as_tensor(HULL_EDGES, device=device)]  # (Hs, 3, 2)
    key = torch.minimum(ends[..., 0], ends[..., 1]) * n + torch.maximum(ends[..., 0], ends[..., 1])
    pos = torch.searchsorted(keys, key).clamp(max=max(keys.shape[0] - 1, 0))
    mixed = hin[:, HULL_EDGES[:, 0]] != hin[:, HULL_EDGES[:, 1]]
    if bool(mixed.any()) and (keys.shape[0] == 0 or bool((mixed & (keys[pos] != key)).any())):
        raise ValueError("hull_faces do not match the tets: a hull edge with a sign change is not a tet edge")
    slots = torch.cat([w_slot, pos], 1)  # (Hs, 6)
    tri = torch.as_tensor(CAP_TABLE, device=device)[code]
    has = tri[..., 0] >= 0
    cap_faces = torch.gather(slots, 1, tri.clamp(min=0).reshape(-1, 6)).reshape(-1, 2, 3)[has]
    return cap_points, cap_faces


def marching_tets_numpy(
    points: np.ndarray,
    tets: np.ndarray,
    s: np.ndarray,
    c: np.ndarray | None = None,
    hull_faces: np.ndarray | None = None,
) -> MarchingTetsResult:
    """Directional marching tets in numpy float64 (no gradients); same output as `marching_tets`.

    Args:
        points: (N, 3) coordinates. tets: (T, 4) positively oriented. s: (N,). c: (N, q) or None.
        hull_faces: optional (H, 3) outward convex hull triangles (closes the surface at the hull).
    Returns:
        MarchingTetsResult of numpy arrays: vertices float64, the rest int64.
    """
    points = np.asarray(points, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    c = None if c is None else np.asarray(c, dtype=np.float64)
    tets = np.ascontiguousarray(tets, dtype=np.int64)
    n = len(points)
    inside = s < 0
    topo = _mt_native.topology(tets, inside, n, _ACTIVE_INT, TRIANGLE_TABLE) if NATIVE else None
    if topo is not None:
        keys = np.frombuffer(topo[0], dtype=np.int64)
        faces = np.frombuffer(topo[1], dtype=np.int64).reshape(-1, 3)
        face_tets = np.frombuffer(topo[2], dtype=np.int64)
    else:
        keys, faces, face_tets = _topology_numpy(tets, inside, n)
    lo, hi = np.divmod(keys, n) if n else (keys, keys)
    lo_in = inside[lo]
    edges = np.stack([np.where(lo_in, lo, hi), np.where(lo_in, hi, lo)], 1)
    vertices = _edge_vertices(points, s, c, edges[:, 0], edges[:, 1])
    if hull_faces is not None and len(hull_faces):
        cap = _caps_numpy(np.asarray(hull_faces, dtype=np.int64), inside, keys, n, len(vertices))
        if cap is not None:
            cap_points, cap_faces = cap
            vertices = np.concatenate([vertices, points[cap_points]], 0)
            edges = np.concatenate([edges, np.stack([cap_points, cap_points], 1)], 0)
            faces = np.concatenate([faces, cap_faces], 0)
            face_tets = np.concatenate([face_tets, np.full(len(cap_faces), -1, dtype=np.int64)])
    check_manifold(faces, len(vertices), closed=hull_faces is not None)
    return MarchingTetsResult(
        np.ascontiguousarray(vertices),
        np.ascontiguousarray(faces, dtype=np.int64),
        np.ascontiguousarray(edges, dtype=np.int64),
        np.ascontiguousarray(face_tets, dtype=np.int64),
    )


def _topology_numpy(tets: np.ndarray, inside: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference topology: sorted unique active edge keys lo * n + hi (U,) (lo < hi), faces (F, 3) into them,
    and the tet of each face (F,); faces by tet, then table order."""
    # The 4 inside flags of a tet as the bytes of one little-endian uint32; mixed tets: not 0, not all ones.
    occ = inside.view(np.uint8)[tets].view("<u4").reshape(-1)
    tet_idx = np.flatnonzero((occ != 0) & (occ != 0x01010101))
    occ = occ[tet_idx]
    code = ((occ & 1) | ((occ >> 7) & 2) | ((occ >> 14) & 4) | ((occ >> 21) & 8)).astype(np.int64)
    mixed = tets[tet_idx]
    key = np.empty((len(mixed), 6), dtype=np.int64)
    for e, (a, b) in enumerate(TET_EDGES.tolist()):
        va, vb = mixed[:, a], mixed[:, b]
        key[:, e] = np.minimum(va, vb) * n + np.maximum(va, vb)
    active = ACTIVE_EDGE_TABLE[code]
    keys, inverse = _unique_inverse(key[active], n)
    slot = np.full(active.shape, -1, dtype=np.int64)
    slot[active] = inverse
    tri = TRIANGLE_TABLE[code]
    has = tri[..., 0] >= 0
    # Flat indices into slot: tet row * 6 + local edge.
    faces = slot.ravel()[(np.arange(len(slot), dtype=np.int64) * 6)[:, None, None] + tri][has]
    face_tets = np.broadcast_to(tet_idx[:, None], has.shape)[has]
    return keys, faces, face_tets


def check_manifold(faces: np.ndarray, num_vertices: int, closed: bool = True) -> None:
    """Raise `TopologyError` unless every directed edge of `faces` is used once (and, if `closed`, has its twin).

    Args:
        faces: (F, 3) int64 triangles into `num_vertices` vertices.
        closed: also require every edge to be shared by exactly two faces in opposite directions (no boundary).
    That is: edge-manifold and consistently oriented (closed: watertight); marching tets on a proper
    tetrahedralization cannot produce anything else, so a failure means its input was not one.
    """
    if not len(faces):
        return
    if NATIVE:
        status = _mt_native.manifold(np.ascontiguousarray(faces, dtype=np.int64), int(num_vertices), closed)
        if status >= 0:  # -1: not decided there (indices out of range, keys beyond 63 bits)
            if status:
                raise TopologyError(_MANIFOLD_ERRORS[status - 1])
            return
    tail = faces.ravel()
    head = faces[:, [1, 2, 0]].ravel()
    if np.any(tail == head):
        raise TopologyError(_MANIFOLD_ERRORS[0])
    # One sort: each directed edge as (undirected key << 1) | direction. Closed and oriented means every
    # undirected key appears exactly twice, once per direction: pairs (2k, 2k + 1) of the sorted array.
    forward = tail * num_vertices + head
    backward = head * num_vertices + tail
    packed = (np.minimum(forward, backward) << 1) | (forward > backward)
    packed.sort()
    if np.any(packed[1:] == packed[:-1]):
        raise TopologyError(_MANIFOLD_ERRORS[1])
    if closed:
        first, second = packed[0::2], packed[1::2]
        if len(first) != len(second) or not np.array_equal(first | 1, second) or np.any(first & 1):
            raise TopologyError(_MANIFOLD_ERRORS[2])


def _unique_inverse(keys: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(keys, return_inverse=True)`` for non-negative keys < n * n, about twice as fast.

    Packs each key with its position into one int64 so that a plain (SIMD) sort replaces numpy's argsort.
    """
    m = len(keys)
    index_bits = max(int(m - 1).bit_length(), 1)
    key_bits = max(int(n * n - 1).bit_length(), 1)
    if m == 0 or key_bits + index_bits > 63:
        return np.unique(keys, return_inverse=True)
    packed = (keys << index_bits) | np.arange(m, dtype=np.int64)
    packed.sort()
    sorted_keys = packed >> index_bits
    first = np.empty(m, dtype=bool)
    first[0] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=first[1:])
    inverse = np.empty(m, dtype=np.int64)
    inverse[packed & ((1 << index_bits) - 1)] = np.cumsum(first) - 1
    return sorted_keys[first], inverse


def _caps_numpy(hull_faces, inside, keys, n, num_vertices):
    hin = inside[hull_faces]
    code = hin[:, 0] + 2 * hin[:, 1].astype(np.int64) + 4 * hin[:, 2]
    sel = code > 0
    if not sel.any():
        return None
    hf, code, hin = hull_faces[sel], code[sel], hin[sel]
    cap_points = np.unique(hf[hin])
    w_slot = num_vertices + np.minimum(np.searchsorted(cap_points, hf), len(cap_points) - 1)
    ends = hf[:, HULL_EDGES]
    key = np.minimum(ends[..., 0], ends[..., 1]) * n + np.maximum(ends[..., 0], ends[..., 1])
    pos = np.minimum(np.searchsorted(keys, key), max(len(keys) - 1, 0))
    mixed = hin[:, HULL_EDGES[:, 0]] != hin[:, HULL_EDGES[:, 1]]
    if (mixed.any() and not len(keys)) or (len(keys) and (mixed & (keys[pos] != key)).any()):
        raise ValueError("hull_faces do not match the tets: a hull edge with a sign change is not a tet edge")
    slots = np.concatenate([w_slot, pos], 1)
    tri = CAP_TABLE[code]
    has = tri[..., 0] >= 0
    cap_faces = np.take_along_axis(slots, tri.reshape(-1, 6), axis=1).reshape(-1, 2, 3)[has]
    return cap_points, cap_faces


def _edge_vertices(points, s, c, i, j):
    """Vertex on each active edge (i inside, j outside), paper eq. 1-2; torch tensors or numpy arrays."""
    is_torch = type(points).__module__.startswith("torch")
    if is_torch:
        import torch

        tanh, where, sqrt = torch.tanh, torch.where, torch.sqrt
    else:  # the format's tanh (geometry/tanh.py): np.tanh is not the same function on every CPU
        tanh, where, sqrt = decoder_tanh, np.where, np.sqrt
    p_i, p_j = points[i], points[j]
    s_i, s_j = s[i], s[j]
    if c is not None and c.shape[-1] > 0:
        degree = degree_from_num_coeffs(int(c.shape[-1]))
        d = p_j - p_i
        length = sqrt((d * d).sum(-1, keepdims=True))
        d = d / where(length > 0, length, length * 0 + 1)
        c_i, c_j = c[i], c[j]
        # SH of i at dir(i -> j) = d and of j at dir(j -> i) = -d, which flips the sign of odd degrees.
        sh_i = d[:, 0] * 0
        sh_j = d[:, 0] * 0
        terms, signs = sh_basis_terms(d, degree), sh_parity(degree).tolist()
        for k, (term, sign) in enumerate(zip(terms, signs, strict=True)):
            sh_i = sh_i + term * c_i[:, k]
            sh_j = sh_j + term * c_j[:, k] if sign > 0 else sh_j - term * c_j[:, k]
        s_i = (1 + tanh(sh_i)) * s_i
        s_j = (1 + tanh(sh_j)) * s_j
    denom = s_j - s_i
    ok = denom != 0
    # s_hat_i underflows to 0 only for saturated tanh; if both ends do, fall back to the midpoint.
    safe = where(ok, denom, denom * 0 + 1)
    w_i = where(ok, s_j / safe, s_j * 0 + 0.5)
    w_j = where(ok, -s_i / safe, s_i * 0 + 0.5)
    return w_i[:, None] * p_i + w_j[:, None] * p_j
