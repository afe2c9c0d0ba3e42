"""Losses of the fit: image reconstruction terms and the TetWeave regularizers (paper §4.1-§4.2, App. B).

Every function is differentiable torch, runs on the device of its inputs and returns a 0-dim tensor that stays
connected to the autograd graph even when there is nothing to penalize (empty face list, no active edge), so
that the caller can always call ``backward`` on the total.

Regularizers
    odt_loss       Optimal Delaunay Triangulation energy of the tetrahedral grid (positions).
    fairness_loss  squared deviation of the extracted triangles' angles from pi/3 (mesh vertices).
    sign_loss      FlexiCubes-style cross-entropy on grid edges whose base signed distance changes sign.
Image terms (paper eq. "recons")
    mask_loss, depth_loss, normal_loss, and image_loss (the fit's weighted sum of them).
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F

# Ratio M_T / M_S of the moment of a tetrahedron about its circumcenter to that of the equal-mass sphere (App.
# B): M_T - M_S = ODT_FACTOR * V * |centroid - circumcenter|^2 and M_S = SHELL_FACTOR * V * R^2.
ODT_FACTOR = 1.6
SHELL_FACTOR = 0.4

# A tetrahedron whose |det[a, b, c]| is below DEGENERATE_DET * (mean squared edge length)^(3/2) is treated as
# flat: its determinant is replaced by that floor so the circumcenter stays finite. The factor is a few
# float32 ulps: below it the determinant is rounding noise anyway.
DEGENERATE_DET = 1e-6
# Smallest magnitude allowed in a denominator: keeps 1/x finite in float32 (1/1e-30 < 3.4e38) for
# all-coincident vertices, where the numerator is exactly zero too.
_TINY = 1e-30

ODT_REDUCTIONS = ("relative", "mean", "sum")


def _zero_like_graph(*tensors: torch.Tensor) -> torch.Tensor:
    """A 0-dim zero that is connected to the autograd graph of ``tensors`` (so ``backward`` always works)."""
    out = None
    for t in tensors:
        if t.is_floating_point():
            term = t.sum() * 0.0
            out = term if out is None else out + term
    if out is None:
        raise TypeError("need at least one floating point tensor")
    return out


# --- ODT ---


def _cross(u: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Cross product of (3,T) component-major vectors."""
    return torch.stack([u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]])


def _dot(u: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(T,) dot product of (3,T) component-major vectors."""
    return u[0] * w[0] + u[1] * w[1] + u[2] * w[2]


def _odt_terms(
    points: torch.Tensor, tets: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Quantities shared by the ODT energies, with a = v1-v0, b = v2-v0, c = v3-v0.

    The circumcenter is v0 + n / (2 det) with n = |a|^2 (b x c) + |b|^2 (c x a) + |c|^2 (a x b) and
    det = a . (b x c), so centroid - circumcenter = m / (2 det) with m = 2 det (centroid - v0) - n and
    R = |n| / (2 |det|). Working with n and m avoids dividing by det where it cancels. Vectors are (3,T)
    component-major: elementwise ops on contiguous rows run about twice as fast as (T,3) with sum(-1).

    Args:
        points: (N,3) float.
        tets: (T,4) long.
    Returns:
        det (T,), guarded_det (T,) (|det| floored, see DEGENERATE_DET), n (3,T), g0 (3,T) = centroid - v0,
        mean squared edge length (T,) (no gradient).
    """
    pt = points.t()
    v0, v1, v2, v3 = (pt[:, tets[:, k]] for k in range(4))
    a, b, c = v1 - v0, v2 - v0, v3 - v0
    bxc = _cross(b, c)
    det = _dot(a, bxc)
    n = _dot(a, a) * bxc + _dot(b, b) * _cross(c, a) + _dot(c, c) * _cross(a, b)
    # Flat tetrahedra have no finite circumcenter: floor |det| relative to the tet's size (no gradient through
    # the floor) so that slivers get a large but finite circumsphere instead of inf/NaN.
    with torch.no_grad():
        sq = (_dot(a, a) + _dot(b, b) + _dot(c, c) + _dot(b - a, b - a) + _dot(c - a, c - a) + _dot(c - b, c - b)) / 6.0
        floor = torch.clamp(DEGENERATE_DET * sq.pow(1.5), min=_TINY)
        sign = torch.where(det < 0, -torch.ones_like(det), torch.ones_like(det))
    guarded = torch.where(det.abs() < floor, sign * floor, det)
    return det, guarded, n, (a + b + c) / 4.0, sq


def odt_energy(points: torch.Tensor, tets: torch.Tensor) -> torch.Tensor:
    """Per-tetrahedron ODT energy of the paper (App. B): E = |M_S - M_T| = 1.6 V |centroid - circumcenter|^2.

    With x_i = v_i - c (c the circumcenter, |x_i| = R) Tonon's formula gives
    M_T = V/5 (sum_i |x_i|^2 + sum_{i<j} x_i.x_j) = V/5 (2 R^2 + |sum_i x_i|^2 / 2)
        = 2/5 V R^2 + 8/5 V |g - c|^2
    (g the centroid, sum_i x_i = 4 (g - c)), and M_S = 2/5 V R^2, so M_T - M_S = 1.6 V |g - c|^2 >= 0.
    Computed as 1.6 / 24 |2 det (g - v0) - n|^2 / |det| (see ``_odt_terms``); det is floored for flat tets,
    whose energy is then large (it grows like 1/V) but finite.

    Args:
        points: (N,3) float.
        tets: (T,4) long.
    Returns:
        (T,) energies in length^5 units, zero exactly for a regular tetrahedron.
    """
    _, det, n, g0, _ = _odt_terms(points, tets)
    m = 2.0 * det * g0 - n
    return (ODT_FACTOR / 24.0) * _dot(m, m) / det.abs()


def odt_relative_energy(points: torch.Tensor, tets: torch.Tensor) -> torch.Tensor:
    """Per-tetrahedron ODT energy relative to the sphere's moment: (M_T - M_S) / M_S = 4 |g - c|^2 / R^2.

    Dimensionless, in [0, 4] (the centroid lies inside the circumsphere), zero exactly where the paper's
    energy is zero (regular tetrahedra). Computed as 4 |2 det (g - v0) - n|^2 / |n|^2, in which det divides
    nothing: a flat tet scores 4 (its circumcenter is at infinity), except a flat tet with its four corners on
    one circle (n = 0, circumsphere undefined), which scores |2 det (g - v0) - n|^2 / floor -> 0, as the
    paper's energy does for slivers.

    Args:
        points: (N,3) float.
        tets: (T,4) long.
    Returns:
        (T,) dimensionless energies.
    """
    det, _, n, g0, sq = _odt_terms(points, tets)
    m = 2.0 * det * g0 - n
    # |n|^2 scales like length^8; floor it relative to the tet's size so that n = 0 gives 0/floor, not 0/0.
    floor = torch.clamp(DEGENERATE_DET**2 * sq.pow(4), min=_TINY)
    return (ODT_FACTOR / SHELL_FACTOR) * _dot(m, m) / torch.maximum(_dot(n, n), floor)


def odt_loss(points: torch.Tensor, tets: torch.Tensor, reduction: str = "relative") -> torch.Tensor:
    """ODT regularizer of the tetrahedral grid (paper §4.2 and App. B).

    Reductions (the paper writes a sum of per-tet energies; its reference code takes their mean):

    ``"relative"`` (default): mean over tets of (M_T - M_S) / M_S = 4 |g - c|^2 / R^2. The absolute energy
        1.6 V |g - c|^2 scales like length^5, so its sum shrinks like h^2 and its mean like h^5 with the point
        spacing
        h: 0.1 * mean is ~1e-7 at 16K points (nothing next to image losses of ~1e-2..1), and the sum is
        dominated (85-90 % measured on random points in a ball, 4K-64K points) by the flat slivers on the
        convex hull, whose energy grows like 1/V. The relative form has the same zero set (regular tets), is
        bounded by 4 per tet, does not depend on the point count (measured 0.88 / 0.80 / 0.76 for random
        points at 4K / 16K / 64K) and is what makes the paper's weight 0.1 a regularizer of the same order as
        the image terms.
    ``"mean"``: mean of the absolute energies (the paper's reference implementation).
    ``"sum"``: sum of the absolute energies (the paper's formula as written).

    Args:
        points: (N,3) float, requires grad for the regularizer to act.
        tets: (T,4) long.
        reduction: one of ``ODT_REDUCTIONS``.
    Returns:
        0-dim tensor; 0 (connected to ``points``) when there is no tetrahedron.
    """
    if reduction not in ODT_REDUCTIONS:
        raise ValueError(f"reduction must be one of {ODT_REDUCTIONS}, got {reduction!r}")
    if tets.shape[0] == 0:
        return _zero_like_graph(points)
    if reduction == "relative":
        return odt_relative_energy(points, tets).mean()
    energy = odt_energy(points, tets)
    return energy.mean() if reduction == "mean" else energy.sum()


# --- Triangle fairness ---

# Edges shorter than sqrt(DEGENERATE_EDGE) times the mesh's RMS edge length have no defined direction, so the
# angles at their ends (and their gradients, which grow like 1/length) are left out of the fairness loss.
DEGENERATE_EDGE = 1e-10


def _corner_angle(u: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(F,) angle between (3,F) edge vectors u and w: atan2(|u x w|, u.w), finite value and gradient."""
    cross = _cross(u, w)
    # sqrt(x + tiny) instead of norm(): norm's gradient at a zero vector is NaN; here it is 0 * finite = 0.
    return torch.atan2(torch.sqrt(_dot(cross, cross) + _TINY), _dot(u, w))


def triangle_angles(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Interior angles of triangles, atan2(|u x w|, u.w), finite for every input (no NaN value or gradient).

    Args:
        vertices: (V,3) float.
        faces: (F,3) long.
    Returns:
        (F,3) angles in radians at corners faces[:, 0], faces[:, 1], faces[:, 2].
    """
    vt = vertices.t()
    p0, p1, p2 = (vt[:, faces[:, k]] for k in range(3))
    e01, e12, e20 = p1 - p0, p2 - p1, p0 - p2
    return torch.stack([_corner_angle(e01, -e20), _corner_angle(e12, -e01), _corner_angle(e20, -e12)], dim=1)


def fairness_loss(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Triangle fairness (paper §4.2): mean over faces of (1/3) sum_i (theta_i - pi/3)^2.

    The paper writes a sum over faces; the mean (as in the reference implementation) keeps the weight 0.35
    meaningful
    whatever the face count: 0 for equilateral triangles, 0.137 for a right isosceles one (angles pi/2, pi/4,
    pi/4), at most (pi - pi/3)^2/3 + 2 (pi/3)^2/3 = 2 pi^2 / 9 = 2.19 for a flat triangle. Faces with a
    (near-)zero-length edge are skipped (their angles are undefined); collinear faces with distinct vertices
    are kept (angles 0, 0, pi, finite gradients).

    Args:
        vertices: (V,3) float.
        faces: (F,3) long.
    Returns:
        0-dim tensor, 0 (connected to ``vertices``) when there is no valid face.
    """
    if faces.shape[0] == 0:
        return _zero_like_graph(vertices)
    with torch.no_grad():
        vt = vertices.t()
        p0, p1, p2 = (vt[:, faces[:, k]] for k in range(3))
        e2 = torch.stack([_dot(p1 - p0, p1 - p0), _dot(p2 - p1, p2 - p1), _dot(p0 - p2, p0 - p2)], dim=1)
        scale = e2.mean()
        valid = (e2 > DEGENERATE_EDGE * scale).all(-1) & (scale > 0)
    if not bool(valid.any()):
        return _zero_like_graph(vertices)
    angles = triangle_angles(vertices, faces[valid])
    return ((angles - math.pi / 3) ** 2).mean()


# --- Sign change ---


def sign_loss(s: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """FlexiCubes' sign-change regularizer (paper §4.2) on grid edges whose base signed distances change sign.

    For each edge (a, b) with (s_a >= 0) != (s_b >= 0) (s >= 0 is outside, as in ``marching_tets``):
    BCE(sigmoid(s_a), s_b >= 0) + BCE(sigmoid(s_b), s_a >= 0), with s used directly as the logit as in
    FlexiCubes' ``sdf_reg_loss``; mean over those edges. It pulls the
    two ends towards each other's sign, i.e. penalizes surface area in places that the images do not
    supervise.

    Args:
        s: (N,) float base signed distances (inside < 0).
        edges: (E,2) long grid edges (unique edges or all six edges of every tet; duplicates weigh more).
    Returns:
        0-dim tensor; 0 (connected to ``s``) when no edge changes sign.
    """
    if edges.shape[0] == 0:
        return _zero_like_graph(s)
    sa = s[edges[:, 0]]
    sb = s[edges[:, 1]]
    outside_a = sa >= 0  # s >= 0 is outside, as in marching_tets
    outside_b = sb >= 0
    change = outside_a != outside_b
    if not bool(change.any()):
        return _zero_like_graph(s)
    sa, sb = sa[change], sb[change]
    loss = F.binary_cross_entropy_with_logits(
        sa, outside_b[change].to(s.dtype), reduction="none"
    ) + F.binary_cross_entropy_with_logits(sb, outside_a[change].to(s.dtype), reduction="none")
    return loss.mean()


# --- Image losses ---

NORMS = ("squared", "l2")


def _pixel_norm(diff: torch.Tensor, norm: str, channels: bool) -> torch.Tensor:
    """Per-pixel squared norm (``"squared"``) or norm (``"l2"``: sqrt(x + 1e-8) as in the reference code)."""
    sq = (diff * diff).sum(-1) if channels else diff * diff
    if norm == "squared":
        return sq
    if norm == "l2":
        return torch.sqrt(sq + 1e-8)
    raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")


def mask_loss(mask: torch.Tensor, mask_gt: torch.Tensor) -> torch.Tensor:
    """L1 silhouette loss, mean over pixels.

    Args:
        mask: (B,H,W) rendered coverage in [0,1] (antialiased, differentiable).
        mask_gt: (B,H,W) target coverage.
    """
    return (mask - mask_gt).abs().mean()


def depth_loss(
    depth: torch.Tensor, depth_gt: torch.Tensor, mask_gt: torch.Tensor, norm: str = "squared"
) -> torch.Tensor:
    """Depth loss ||M_gt (D - D_gt)||^2 of the paper, mean over all B*H*W pixels (background counts as 0).

    Args:
        depth, depth_gt: (B,H,W) camera-space depth (0 on background).
        mask_gt: (B,H,W) target coverage, weights the per-pixel difference.
        norm: ``"squared"`` (paper's equation) or ``"l2"`` (|.|, the reference implementation, where lambda_D
            = 250 was tuned).
    """
    return _pixel_norm(mask_gt * (depth - depth_gt), norm, channels=False).mean()


def normal_loss(
    normals: torch.Tensor, normals_gt: torch.Tensor, mask_gt: torch.Tensor, norm: str = "squared"
) -> torch.Tensor:
    """Normal loss ||M_gt (N - N_gt)||^2 of the paper: per-pixel squared norm of the 3-vector, pixel mean.

    Args:
        normals, normals_gt: (B,H,W,3) world-space normals.
        mask_gt: (B,H,W) target coverage.
        norm: ``"squared"`` or ``"l2"`` (see ``depth_loss``).
    """
    return _pixel_norm(mask_gt.unsqueeze(-1) * (normals - normals_gt), norm, channels=True).mean()


def image_loss(maps: Any, target_maps: Any, weights: Any) -> tuple[torch.Tensor, dict[str, float]]:
    """The fit's image term: paper's L_recons, with depth and normals compared only where both the target and the
    render see a surface.

    The paper masks depth and normals by the target's mask alone; then a target pixel that the current mesh misses
    compares the target's depth with the background's 0, an error of ~3 units that outweighs every interior pixel
    and mostly pushes silhouettes around, which the (antialiased) mask term already does. Depth is compared with
    |.| as in the paper's reference code (for which lambda_D = 250 was tuned), normals with |.|^2.

    Args:
        maps: rendered RenderMaps (mask (B,H,W), depth (B,H,W), normals (B,H,W,3), fragments.face_id (B,H,W)).
        target_maps: the input's maps (mask, depth, normals).
        weights: an object with float attributes mask, depth, normals (fit.config.Weights).
    Returns:
        (total, parts): the weighted sum (0-dim tensor) and the weighted terms as floats, for logging.
    """
    both = target_maps.mask * (maps.fragments.face_id >= 0).to(target_maps.mask.dtype)
    mask = mask_loss(maps.mask, target_maps.mask) * weights.mask
    depth = depth_loss(maps.depth, target_maps.depth, both, norm="l2") * weights.depth
    normals = normal_loss(maps.normals, target_maps.normals, both) * weights.normals
    total = mask + depth + normals
    return total, {"mask": float(mask.detach()), "depth": float(depth.detach()), "normals": float(normals.detach())}
