"""The surface a viewer sees: the input's faces seen from outside in offscreen renders, oriented towards the views.

Real assets are often not clean closed surfaces: parts hidden inside a housing, a second (inner) wall, primitives
that overlap without a boolean union, faces with random orientation. A viewer shows them correctly; the winding
number does not (it cancels on random orientation, counts hidden parts and internal walls as surface). This module
renders the normalized input from VIEWS near-orthographic cameras on a Fibonacci sphere (no back-face culling:
orientation-free) into face-id buffers (render.visibility) and derives:

- which faces some view sees (the visible surface; hidden parts and internal walls drop out). A face counts as
  seen when it covers a pixel centre in some view, or its centroid lies within DEPTH_TOLERANCE pixels of the depth
  buffer there (faces smaller than a pixel). A seen face with a corner no view sees, or (longer than WHOLE_PIXELS
  pixels) a point of a grid WHOLE_PIXELS pixels apart on it, is split at its edge midpoints until the pieces at
  the seam are about a pixel long (not a fixed number of levels; at most MAX_REFINED_FACES faces, InputError
  beyond): a long face that another part cuts through keeps only its seen pieces (issue 55: five levels left
  strips of long faces inside the solid);
- the orientation of each seen face: flipped when most views that see it see its back. The seen faces of a closed
  shape are then an outward-oriented surface, and the winding number's sign (fit.initialize.signed_distance) is
  that of the surface a viewer sees, whatever the input's own orientation;
- `outside_surface`: closed parts need no renders. The exact union of the input's closed parts (fit.parts,
  manifold3d: hidden parts and overlaps resolved exactly), plus the input's other faces (open parts, sheets,
  soups, inconsistently oriented parts) as renders of them see them, less what lies inside the union;
- `choose_surface`: what "auto" fits. Closed parts that overlap or nest (their union drops more than
  HIDDEN_AREA_SHARE of their area): the exact union. One closed part, or closed parts that are disjoint or touch:
  the whole input (a clean closed scan keeps the crevices no view sees into, a character its parts). Without
  closed parts: the visible surface when the faces are not consistently oriented after welding by position, or
  when more than HIDDEN_AREA_SHARE of the area is seen by no view; else the whole input. Clean closed inputs (and
  open scans, whose holes show their insides) keep the whole input, exactly today's encode.

A cavity that no outside view sees (the inside of a closed box) is not part of the visible surface.

    surface = visible_surface(normalized, faces)     # VisibleSurface: vertices (V',3), faces (F',3), stats
    surface = outside_surface(normalized, faces)     # the same, closed parts by their exact union
    choice = choose_surface(normalized, faces, "auto")  # SurfaceChoice(mode, reason, surface | None)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tetweave_codec.errors import InputError
from tetweave_codec.geometry.triangles import face_areas, face_normals
from tetweave_codec.options import SURFACES
from tetweave_codec.render.visibility import MAX_FACES, Renders, bounding_radius, pixel_size, render

# Seen faces with a corner no view sees are split (each child a quarter) until the pieces at the seam are at most
# a pixel long, within these bounds: the output's faces (InputError beyond), and levels (a face 2^24 pixels long).
MAX_REFINED_FACES = 2_000_000
MAX_REFINE_LEVELS = 24
# A seen face whose corners some view sees is kept whole only when points on it at most this many pixels apart are
# seen too: a long face whose corners lie outside another part can still pass through it (a sheet through a
# solid); hidden stretches narrower than this between seen points are what stays.
WHOLE_PIXELS = 8
# Points tested at once by `_face_points_seen` (memory: views x points booleans and a few float arrays of points).
POINT_CHUNK = 200_000
# The non-closed faces that `outside_surface` keeps beside closed parts (sheets, cards) become a closed slab this
# thick (normalized frame, fit.parts.thin_slab): a single-sided square through spot at --size 5k came out with holes
# over 16 % of it (6.4e-3 against spot + the square); given as a 0.0075-thick box, 3.7e-3 (docs/measurements/
# parts.md). 0 keeps them open.
SHEET_THICKNESS = 0.0075
# A sheet closer than this to the closed parts (a shirt on a body) is a slab down to them: no viewer sees into
# the narrow gap between them, and the union of slab and body has none (normalized frame, fit.parts.thin_slab).
SHEET_REACH = 0.03
# "auto" takes the visible surface when more than this share of the input's area is seen by no view (or lies inside
# other closed parts).
HIDDEN_AREA_SHARE = 0.01


@dataclass(frozen=True)
class VisibleSurface:
    """The seen faces of the (refined) normalized input, each oriented towards the views that see it.

    vertices (V',3) float64 (normalized frame), faces (F',3) int64; hidden_share: the input's area seen by no
    view over its total area (`outside_surface`: of the input's area not on the surface); flipped: seen faces turned
    to face their views; refined: faces after the split; method: "rendered", "union" (closed parts only) or
    "union+rendered"; closed_parts: the closed parts in the union."""

    vertices: np.ndarray
    faces: np.ndarray
    hidden_share: float
    flipped: int
    refined: int
    method: str = "rendered"
    closed_parts: int = 0


@dataclass(frozen=True)
class SurfaceChoice:
    """What an encode fits: mode "visible" or "all", why (one phrase for the summary), and the visible surface when
    the mode is "visible"."""

    mode: str
    reason: str
    surface: VisibleSurface | None = None
    outside_differs: bool = False  # mode "all" although the outside surface is another (open or unoriented pieces)


def _split(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each face (F,3) into four at its edge midpoints (new vertices appended, one per face edge): children
    (4F,3), child k of face i at row 4i + k, each oriented as its parent."""
    a, b, c = faces.T
    n = len(vertices)
    m = len(faces)
    mids = np.concatenate(
        [0.5 * (vertices[b] + vertices[c]), 0.5 * (vertices[c] + vertices[a]), 0.5 * (vertices[a] + vertices[b])]
    )
    ma, mb, mc = n + np.arange(m), n + m + np.arange(m), n + 2 * m + np.arange(m)
    children = np.stack([np.stack(t, axis=1) for t in ((a, mc, mb), (mc, b, ma), (mb, ma, c), (ma, mb, mc))], axis=1)
    return np.concatenate([vertices, mids]), children.reshape(-1, 3)


def _orient(renders: Renders, v: np.ndarray, f: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(F,) bool: faces (F,3) that most views seeing them (seen (B,F)) see from the back: to be flipped."""
    normals = face_normals(v, f)
    centroid = v[f].mean(axis=1)
    votes = np.zeros(len(f))
    for b, eye in enumerate(renders.eyes):
        votes += np.where(seen[b], np.sign(np.einsum("fj,fj->f", normals, eye - centroid)), 0.0)
    return votes < 0


def _longest(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) the longest edge of each face (F,3)."""
    return np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, axis=1)], axis=2).max(axis=1)


def _seen_by(renders: Renders):
    """seen(points (P,3), normals (P,3) | None) -> (P,) bool: some view of `renders` sees the point."""
    return lambda points, normals=None: renders.points_seen(points, normals).any(axis=0)


def _face_points_seen(seen, v: np.ndarray, f: np.ndarray, pixel: float) -> tuple[np.ndarray, np.ndarray]:
    """(all (F,), some (F,)) bool: whether every / some point of faces (F,3) tested is seen: the corners, the
    centroid, and for faces longer than WHOLE_PIXELS pixels a barycentric grid at most WHOLE_PIXELS pixels apart."""
    every = np.ones(len(f), dtype=bool)
    some = np.zeros(len(f), dtype=bool)
    steps = np.maximum(np.ceil(_longest(v, f) / (WHOLE_PIXELS * pixel)).astype(np.int64), 1)
    normals = face_normals(v, f)
    for n in np.unique(steps):
        rows = np.flatnonzero(steps == n)
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        bary = np.stack([i.ravel(), j.ravel(), n - i.ravel() - j.ravel()], axis=1)
        bary = np.concatenate([bary[(bary >= 0).all(axis=1)] / n, np.full((1, 3), 1.0 / 3.0)])  # (K,3)
        per = max(1, POINT_CHUNK // len(bary))
        for start in range(0, len(rows), per):
            r = rows[start : start + per]
            points = np.einsum("kc,fcj->fkj", bary, v[f[r]]).reshape(-1, 3)
            ok = seen(points, np.repeat(normals[r], len(bary), axis=0)).reshape(len(r), len(bary))
            every[r], some[r] = ok.all(axis=1), ok.any(axis=1)
    return every, some


def _whole(seen, pixel: float, v: np.ndarray, f: np.ndarray, any_seen: np.ndarray, corner_seen: np.ndarray):
    """(F,) bool: seen faces (F,3) kept whole: every corner seen (corner_seen (V,)) and their inside
    (`_face_points_seen`)."""
    whole = any_seen & corner_seen[f].all(axis=1)
    rows = np.flatnonzero(whole)
    whole[rows] = _face_points_seen(seen, v, f[rows], pixel)[0]
    return whole


def _seen_pieces(
    seen, pixel: float, v: np.ndarray, faces: np.ndarray, parent: np.ndarray, budget: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seen faces (F,3) with a corner no view sees (a seam where another part cuts through), split at their edge
    midpoints while longer than a pixel, keeping the children some view sees: the pieces at a seam end about a
    pixel long, however long their face. parent (F,): each face's input face. Returns (vertices (V',3): v then
    the midpoints, pieces (P,3), their parents (P,)). seen: `_seen_by`'s test (or another); pixel: a pixel's
    world length. InputError when the pieces would exceed `budget` faces."""
    done = []
    count = 0
    todo, out_v = faces, v
    for _ in range(MAX_REFINE_LEVELS):
        if not len(todo):
            break
        small = _longest(out_v, todo) <= pixel
        done.append((todo[small], parent[small]))
        count += int(small.sum())
        if count + 4 * int((~small).sum()) > budget:
            raise InputError(
                f"mesh: splitting the visible surface's seams to a pixel needs more than {budget:,} faces "
                "(long faces cut by other parts); encode with --surface all"
            )
        out_v, children = _split(out_v, todo[~small])
        parent = np.repeat(parent[~small], 4)
        # a child nothing of which is seen drops out, one all of whose tested points are seen is kept whole
        every, some = _face_points_seen(seen, out_v, children, pixel)
        done.append((children[every], parent[every]))
        count += int(every.sum())
        todo, parent = children[some & ~every], parent[some & ~every]
    done.append((todo, parent))
    return out_v, np.concatenate([d[0] for d in done]), np.concatenate([d[1] for d in done])


def _assemble(
    v: np.ndarray, out_v: np.ndarray, pieces: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """The output mesh: pieces [(faces (P,3) into out_v, order key (P,))] in order of their keys (stable), the
    midpoints (out_v past len(v)) welded where equal, unused vertices dropped (the rest keep their order)."""
    out_f = np.concatenate([p[0] for p in pieces]).reshape(-1, 3)
    order = np.argsort(np.concatenate([p[1] for p in pieces]), kind="stable")
    out_f = out_f[order]
    # Midpoints of an edge both of whose faces were split are one vertex (the same float sum either way).
    if len(out_v) > len(v):
        mids, weld = np.unique(out_v[len(v) :], axis=0, return_inverse=True)
        out_f = np.concatenate([np.arange(len(v)), len(v) + weld.reshape(-1)])[out_f]
        out_v = np.concatenate([v, mids])
    used, inverse = np.unique(out_f, return_inverse=True)
    return out_v[used], inverse.reshape(-1, 3).astype(np.int64)


def _usable(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) bool: faces with a finite, positive area."""
    area = face_areas(vertices, faces)
    return np.isfinite(area) & (area > 0) & np.isfinite(vertices[faces]).all(axis=(1, 2))


def visible_surface(vertices: np.ndarray, faces: np.ndarray) -> VisibleSurface:
    """The faces of the normalized input (vertices (V,3), faces (F,3)) seen from outside in renders, oriented
    towards their views; seen faces with a corner no view sees (a seam where another part cuts through) are split
    at their edge midpoints until the pieces at the seam are about a pixel long (`_seen_pieces`, at most
    MAX_REFINED_FACES faces), keeping the seen children. hidden_share: the input's area on faces no view sees.
    InputError when no face is seen (nothing a viewer would show)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    keep = _usable(v, f)
    if not keep.any():
        raise InputError("mesh: no face has a visible area")
    f = f[keep]
    _check_size(len(f))
    renders = render(v, f)
    seen, corner_seen = renders.faces_seen(v)  # (B,F), (B,V)
    corner_seen = corner_seen.any(axis=0)
    flip = _orient(renders, v, f, seen)
    any_seen = seen.any(axis=0)
    area = face_areas(v, f)
    hidden_share = float(area[~any_seen].sum() / area.sum())
    if not any_seen.any():
        raise InputError("mesh: no face has a visible area")
    oriented = f.copy()
    oriented[flip] = oriented[flip][:, ::-1]
    # Each piece remembers its input face: the output keeps the input's face order (a clean input's faces come
    # out as they went in).
    seen_fn, pixel = _seen_by(renders), pixel_size(renders.resolution, bounding_radius(v, f))
    whole = _whole(seen_fn, pixel, v, oriented, any_seen, corner_seen)
    part = any_seen & ~whole
    budget = MAX_REFINED_FACES - int(whole.sum())
    out_v, pieces, parent = _seen_pieces(seen_fn, pixel, v, oriented[part], np.flatnonzero(part), budget)
    out_v, out_f = _assemble(v, out_v, [(oriented[whole], np.flatnonzero(whole)), (pieces, parent)])
    return VisibleSurface(out_v, out_f, hidden_share, int((flip & any_seen).sum()), len(out_f))


def outside_surface(vertices: np.ndarray, faces: np.ndarray, parts=None, union=None) -> VisibleSurface:
    """The outside surface of the normalized input (vertices (V,3), faces (F,3)): the exact union of its closed
    parts (fit.parts, manifold3d), and the pieces of its other faces (open parts, sheets, soups, inconsistently
    oriented parts) that renders of those faces alone see (they may hide each other) and that lie outside the
    union (its winding number, exact: no pixels), split to a pixel at seams (`_seen_pieces`). A stretch of a
    sheet that only the union hides from the views (a crevice between a sheet and the solid) is kept, as the
    union keeps its own crevices. The union's faces are exact and kept whole, except those that some view of the
    union alone sees but none sees with the other faces in front (hidden by an open part, e.g. inside an open
    housing: a viewer does not see them).
    Without closed parts this is `visible_surface`. parts: fit.parts.Parts of the input, when already split;
    union: fit.parts.Union of those parts, when already computed.
    hidden_share: the share of the input's area not on the output (hidden or inside the union)."""
    from tetweave_codec.fit.parts import closed_union, split_parts

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    parts = split_parts(v, f) if parts is None else parts
    if not len(parts.closed):
        return visible_surface(v, f)
    total = float(face_areas(v, f)[_usable(v, f)].sum())
    union = closed_union(v, f, parts) if union is None else union
    rest = np.flatnonzero(parts.rest & _usable(v, f))
    n_closed = len(parts.closed)
    if not len(rest):
        out_v, out_f = _assemble(union.vertices, union.vertices, [(union.faces, np.arange(len(union.faces)))])
        share = max(0.0, 1.0 - union.area / total)
        return VisibleSurface(out_v, out_f, share, int(parts.inverted.sum()), len(out_f), "union", n_closed)
    cv = union.vertices
    nu = len(union.faces)
    rest_f = f[rest]
    cf = np.concatenate([union.faces, rest_f])
    _check_size(len(cf))
    # the union's faces: hidden ones are dropped only when the other faces hide them (seen without those)
    keep_union = render(cv, cf).faces_seen()[0][:, :nu].any(axis=0)
    if not keep_union.all():
        keep_union |= ~render(cv, union.faces).faces_seen()[0].any(axis=0)
    # the other faces: what renders of them alone see (they may hide each other), less what lies inside the union
    # (exact: its winding number; a crevice between a sheet and the solid is kept, as the union keeps its own)
    from tetweave_codec.fit.initialize import signed_distance

    renders = render(cv, rest_f)
    pixel = pixel_size(renders.resolution, bounding_radius(cv, cf))
    uv, uf = union.vertices, union.faces

    def seen_fn(points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        ok = renders.points_seen(points, normals).any(axis=0)
        rows = np.flatnonzero(ok)
        if len(rows):
            ok[rows] = signed_distance(points[rows], uv, uf) > -renders.tol
        return ok

    seen, _ = renders.faces_seen()
    any_seen = seen.any(axis=0)
    flip = _orient(renders, cv, rest_f, seen)
    oriented = rest_f.copy()
    oriented[flip] = oriented[flip][:, ::-1]
    corner_seen = np.zeros(len(cv), dtype=bool)
    corners = np.unique(rest_f[any_seen])
    corner_seen[corners] = seen_fn(cv[corners])
    whole = _whole(seen_fn, pixel, cv, oriented, any_seen, corner_seen)
    part = any_seen & ~whole
    budget = MAX_REFINED_FACES - int(whole.sum()) - nu
    out_v, pieces, parent = _seen_pieces(seen_fn, pixel, cv, oriented[part], nu + np.flatnonzero(part), budget)
    rest_seen = any_seen
    groups = [(uf[keep_union], np.flatnonzero(keep_union)), (oriented[whole], nu + np.flatnonzero(whole))]
    out_v, out_f = _assemble(cv, out_v, [*groups, (pieces, parent)])
    if not len(out_f):
        raise InputError("mesh: no face has a visible area")
    share = max(0.0, 1.0 - float(face_areas(out_v, out_f).sum()) / total)
    flipped = int(parts.inverted.sum() + (flip & rest_seen).sum())
    # the other faces' pieces as a thin closed slab: an open sheet fitted as it is comes out as a slab with holes
    from tetweave_codec.fit.parts import thin_slab, union_with

    n_union = int(keep_union.sum())
    if SHEET_THICKNESS > 0 and len(out_f) > n_union:
        sv, sf = thin_slab(out_v, out_f[n_union:], SHEET_THICKNESS, (uv, uf), SHEET_REACH)
        # the slab and the whole union as one closed surface (the union's faces only the sheets hid included: a
        # shirt's slab reaching the body beneath seals what it covers; a farther gap stays, as a viewer's crevice)
        merged = union_with(uv, uf, sv, sf)
        if merged is not None:
            out_v, out_f = merged
        else:
            used, inverse = np.unique(out_f[:n_union], return_inverse=True)
            out_v = np.concatenate([out_v[used], sv])
            out_f = np.concatenate([inverse.reshape(-1, 3), sf + len(used)]).astype(np.int64)
    return VisibleSurface(out_v, out_f, share, flipped, len(out_f), "union+rendered", n_closed)


def _check_size(n_faces: int) -> None:
    """InputError when the (view, face) arrays of `n_faces` faces would exceed memory."""
    if n_faces > MAX_FACES:
        raise InputError(f"mesh: {n_faces:,} faces are more than the {MAX_FACES:,} the visible surface can render")


def orientation_consistent(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether, after welding vertices at equal positions, no directed edge is used by two faces (every shared
    edge is traversed in opposite directions by its faces: a consistent orientation)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _, weld = np.unique(v, axis=0, return_inverse=True)
    wf = weld.reshape(-1)[f]
    wf = wf[(wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 2] != wf[:, 0])]
    directed = np.concatenate([wf[:, [0, 1]], wf[:, [1, 2]], wf[:, [2, 0]]])
    _, counts = np.unique(directed, axis=0, return_counts=True)
    return bool((counts <= 1).all())


def choose_surface(vertices: np.ndarray, faces: np.ndarray, surface: str) -> SurfaceChoice:
    """What the encode fits for `surface` in SURFACES, with its reason; vertices (V,3) normalized, faces (F,3).

    "all": the whole input (no renders). "visible": `outside_surface` (the exact union of the closed parts, renders
    for the rest). "auto", by the input's parts (fit.parts.split_parts):
    - only closed parts: one part, or parts whose union drops at most HIDDEN_AREA_SHARE of their area (disjoint,
      touching, a small part inside another) keep the whole input: a clean closed scan keeps its deep crevices,
      a character its parts. Parts that overlap or nest take their exact union;
    - no closed part (open scans, sheets, soups, inconsistent orientation): the rendered visible surface when the
      orientation is inconsistent or more than HIDDEN_AREA_SHARE of the area is hidden from every view, else all;
    - both: `outside_surface` when the non-closed faces are inconsistently oriented or it drops more than
      HIDDEN_AREA_SHARE of the area, else all."""
    from tetweave_codec.fit.parts import closed_union, split_parts

    if surface not in SURFACES:
        raise InputError(f"surface must be one of {', '.join(SURFACES)}, got {surface!r}")
    if surface == "all":
        return SurfaceChoice("all", "--surface all")
    if surface == "auto" and len(faces) > MAX_FACES:
        return SurfaceChoice("all", f"more than {MAX_FACES:,} faces, too many to render for the visible surface")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    parts = split_parts(v, f)
    n_closed = len(parts.closed)
    if surface == "visible":
        out = outside_surface(v, f, parts)
        return SurfaceChoice("visible", f"--surface visible; {_describe(out)}", out)
    if n_closed and not parts.rest.any():
        if n_closed == 1 and not parts.duplicate.any():
            return SurfaceChoice("all", "a consistently oriented surface, one closed part")
        union = closed_union(v, f, parts)
        dropped = max(0.0, 1.0 - union.area / union.parts_area)
        if dropped <= HIDDEN_AREA_SHARE:
            return SurfaceChoice(
                "all", f"{n_closed} closed parts, disjoint or touching ({_pct(dropped)} inside others)"
            )
        out = outside_surface(v, f, parts, union)
        return SurfaceChoice("visible", _describe(out), out)
    if n_closed:
        out = outside_surface(v, f, parts)
        rest = f[parts.rest]
        if not orientation_consistent(v, rest):
            return SurfaceChoice("visible", f"faces with inconsistent orientation; {_describe(out)}", out)
        if out.hidden_share > HIDDEN_AREA_SHARE:
            return SurfaceChoice("visible", _describe(out), out)
        reason = f"closed and open parts, {_pct(out.hidden_share)} of the area hidden or inside"
        return SurfaceChoice("all", reason, outside_differs=True)
    consistent = orientation_consistent(v, f)
    visible = visible_surface(v, f)
    hidden = f"{_pct(visible.hidden_share)} of its area hidden from every view"
    if not consistent:
        return SurfaceChoice("visible", f"faces with inconsistent orientation; {hidden}", visible)
    if visible.hidden_share > HIDDEN_AREA_SHARE:
        return SurfaceChoice("visible", hidden, visible)
    return SurfaceChoice("all", f"a consistently oriented surface, {hidden}", outside_differs=True)


def _pct(share: float) -> str:
    return f"{100 * share:.1f} %"


def _describe(surface: VisibleSurface) -> str:
    """One phrase for the summary: how the surface was made and what share of the input's area it dropped."""
    if surface.method == "rendered":
        return f"{_pct(surface.hidden_share)} of its area hidden from every view"
    what = f"the exact union of {surface.closed_parts} closed part{'s' if surface.closed_parts != 1 else ''}"
    if surface.method == "union+rendered":
        what += ", the other faces as renders see them"
    return f"{what}; {_pct(surface.hidden_share)} of the area dropped (hidden or inside)"
