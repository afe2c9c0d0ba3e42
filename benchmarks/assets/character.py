"""A character made of parts (no CAD kernel: manifold3d's level set and numpy), as a sculpt export holds it.

Parts, in metres (1.8 tall), never booleaned:

    body     a smooth union (polynomial smooth minimum) of a torso and neck capsule, a head sphere, arm and leg
             capsules, meshed by manifold3d's level set and decimated (closed)
    shirt    an open tube around the torso, about 5 mm off it, single-sided, open at both ends
    belt     a closed ring through the shirt's lower rim and the body
    eyes     two spheres half sunk into the head (closed), a pupil each: an open disk just in front of the eye
    teeth    an upper row of six closed boxes half inside the head, neighbours sharing a side (welded: edges with
             four faces), a lower row as one open strip
    hat      a closed crown sunk into the head, an open brim (annulus sheet) around it sharing the crown's base
             circle (welded, edges with four faces)

`clean()`: the same character as a careful artist would deliver it: one closed surface, manifold3d's union of the
closed parts, the shirt as a filled tube (its side the sheet's polygon), the other open parts thickened to closed
shells SHEET thick. It is the clean input the encodes are compared with; the truth of what a viewer sees is the
ray-cast samples of the parts (`raycast.visible_samples`): the union of open surfaces has no boolean definition.
"""

from __future__ import annotations

import numpy as np

SHEET = 0.0005  # the clean version's thickness of the open parts
SHIRT = (0.175, 0.98, 1.30)  # radius, bottom, top: 5 mm off the torso's capsule (the smooth union pokes through)
EDGE = 0.03  # the level set's edge length
BODY_FACES = 3600  # the body decimated to this (fast-simplification's quadrics): small committed files


def _capsule_sdf(p: np.ndarray, a, b, r: float) -> float:
    a, b = np.asarray(a), np.asarray(b)
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-300), 0.0, 1.0)
    return r - float(np.linalg.norm(p - (a + t * ab)))  # positive inside (manifold3d's convention)


def _smooth_max(a: float, b: float, k: float) -> float:
    """Smooth union of two inside-positive distances (the polynomial smooth minimum of their negatives)."""
    h = max(k - abs(a - b), 0.0) / k
    return max(a, b) + h * h * k * 0.25


CAPSULES = [
    ((0.0, 0.0, 0.95), (0.0, 0.0, 1.30), 0.17),  # torso
    ((0.0, 0.0, 1.30), (0.0, 0.0, 1.50), 0.06),  # neck
    ((0.0, 0.0, 1.58), (0.0, 0.0, 1.58), 0.13),  # head
    ((-0.17, 0.0, 1.36), (-0.55, 0.0, 1.00), 0.05),  # arms
    ((0.17, 0.0, 1.36), (0.55, 0.0, 1.00), 0.05),
    ((-0.09, 0.0, 0.92), (-0.12, 0.0, 0.06), 0.07),  # legs
    ((0.09, 0.0, 0.92), (0.12, 0.0, 0.06), 0.07),
]
HEAD = (np.array([0.0, 0.0, 1.58]), 0.13)


def body():
    import manifold3d

    def sdf(x, y, z):
        p = np.array([x, y, z])
        d = -1.0
        for a, b, r in CAPSULES:
            d = _smooth_max(d, _capsule_sdf(p, a, b, r), 0.06)
        return d

    import fast_simplification

    v, f = _arrays(manifold3d.Manifold.level_set(sdf, [-0.7, -0.3, -0.05, 0.7, 0.3, 1.8], EDGE))
    v, f = fast_simplification.simplify(v, f, target_reduction=1.0 - BODY_FACES / len(f))
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def _arrays(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh64()
    return np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy(), np.array(mesh.tri_verts, dtype=np.int64)


def _head_point(azimuth: float, z: float, out: float = 0.0) -> np.ndarray:
    """The point of the head sphere at height z, azimuth measured from -y (the face), moved `out` outwards."""
    c, r = HEAD
    rho = np.sqrt(max(r * r - (z - c[2]) ** 2, 0.0)) + out
    return np.array([rho * np.sin(azimuth), -rho * np.cos(azimuth), z])


def tube(radius: float, z0: float, z1: float, sections: int = 40, rings: int = 6):
    """An open cylinder (no caps) around the z axis, outward-oriented."""
    a = 2 * np.pi * np.arange(sections) / sections
    z = np.linspace(z0, z1, rings + 1)
    x, y = np.tile(radius * np.cos(a), rings + 1), np.tile(radius * np.sin(a), rings + 1)
    v = np.stack([x, y, np.repeat(z, sections)], axis=1)
    faces = []
    for i in range(rings):
        for j in range(sections):
            p, q = i * sections + j, i * sections + (j + 1) % sections
            faces += [(p, q, q + sections), (p, q + sections, p + sections)]
    return v, np.array(faces, dtype=np.int64)


def _ring(centre, normal, radius: float, sections: int) -> np.ndarray:
    """(sections, 3) points on a circle around `centre` in the plane of `normal` (the same floats for every caller
    with the same arguments: parts built on one ring share its vertices exactly)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    a = 2 * np.pi * np.arange(sections) / sections
    return np.asarray(centre, dtype=np.float64) + radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * w)


def disk(centre, normal, r_in: float, r_out: float, sections: int = 24):
    """An open flat annulus (r_in = 0: a disk) facing `normal`."""
    c = np.asarray(centre, dtype=np.float64)
    if r_in == 0:
        v = np.concatenate([c[None], _ring(c, normal, r_out, sections)])
        f = [(0, 1 + j, 1 + (j + 1) % sections) for j in range(sections)]
    else:
        v = np.concatenate([_ring(c, normal, r_in, sections), _ring(c, normal, r_out, sections)])
        f = []
        for j in range(sections):
            k = (j + 1) % sections
            f += [(j, sections + j, sections + k), (j, sections + k, k)]
    return v, np.array(f, dtype=np.int64)


def frustum(base, r0: float, r1: float, height: float, sections: int = 32):
    """A closed frustum along +z from `base` (radius r0 there, r1 at the top), outward-oriented; its base circle is
    `_ring(base, z, r0, sections)` exactly."""
    b = np.asarray(base, dtype=np.float64)
    top = b + [0.0, 0.0, height]
    v = np.concatenate([_ring(b, (0, 0, 1), r0, sections), _ring(top, (0, 0, 1), r1, sections), [b, top]])
    n = sections
    f = []
    for j in range(n):
        k = (j + 1) % n
        f += [(j, k, n + k), (j, n + k, n + j), (2 * n, k, j), (2 * n + 1, n + j, n + k)]
    f = np.array(f, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    if np.einsum("ij,ij->i", v[f[:, 0]], cross).sum() < 0:
        f = f[:, ::-1]
    return v, f


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box between corners lo and hi, outward-oriented, two triangles per side."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v = np.array([[(lo, hi)[(i >> k) & 1][k] for k in range(3)] for i in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return v, f


def _teeth_strip(z: float, width: float, count: int = 8):
    """The lower teeth: an open strip following the head's front, half a tooth out of it."""
    az = np.linspace(-0.45, 0.45, count + 1)
    top = np.array([_head_point(a, z + width / 2, 0.004) for a in az])
    bottom = np.array([_head_point(a, z - width / 2, 0.004) for a in az])
    v = np.concatenate([top, bottom])
    f = []
    for j in range(count):
        f += [(j, j + count + 1, j + count + 2), (j, j + count + 2, j + 1)]
    return v, np.array(f, dtype=np.int64)


def parts() -> list[tuple[str, tuple[np.ndarray, np.ndarray], bool]]:
    """[(name, (vertices, faces), closed)]."""
    import manifold3d

    out = [("body", body(), True)]
    out.append(("shirt", tube(*SHIRT), False))
    belt = manifold3d.Manifold.cylinder(0.04, 0.205, 0.205, 48).translate((0, 0, 0.96)) - manifold3d.Manifold.cylinder(
        0.06, 0.16, 0.16, 48
    ).translate((0, 0, 0.95))
    out.append(("belt", _arrays(belt), True))
    for side in (-1, 1):
        eye_c = _head_point(side * 0.36, 1.61, -0.006)
        eye = manifold3d.Manifold.sphere(0.024, 24).translate(tuple(eye_c))
        out.append((f"eye{'lr'[side > 0]}", _arrays(eye), True))
        outward = eye_c - HEAD[0]
        outward /= np.linalg.norm(outward)
        out.append((f"pupil{'lr'[side > 0]}", disk(eye_c + 0.0245 * outward, outward, 0.0, 0.01, 16), False))
    # the upper teeth: a straight row of boxes, each sharing its side faces' corners with its neighbours exactly
    xs = np.linspace(-0.045, 0.045, 7)
    for k in range(6):
        out.append((f"tooth{k}", box((xs[k], -0.118, 1.505), (xs[k + 1], -0.098, 1.525)), True))
    out.append(("teeth_low", _teeth_strip(1.49, 0.016), False))
    # the hat: a crown sunk into the head and a brim whose inner rim is the crown's base circle (the same vertices:
    # a one-mesh export welds them, and that loop's edges get four faces)
    out.append(("crown", frustum((0.0, 0.0, 1.665), 0.11, 0.10, 0.1, 32), True))
    out.append(("brim", disk((0.0, 0.0, 1.665), (0.0, 0.0, 1.0), 0.11, 0.22, 32), False))
    return out


def _thick(v: np.ndarray, f: np.ndarray, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """An open, consistently oriented surface as a closed shell: both sides moved thickness / 2 along the vertex
    normals, the boundary closed by walls (each part here is one strip, tube or disk)."""
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], cross)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    n = len(v)
    out_v = np.concatenate([v + 0.5 * thickness * normals, v - 0.5 * thickness * normals])
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * n + directed[:, 1]
    a, b = directed[~np.isin(key, directed[:, 1] * n + directed[:, 0])].T
    walls = np.concatenate([np.stack([b, a, a + n], axis=1), np.stack([b, a + n, b + n], axis=1)])
    return out_v, np.concatenate([f, f[:, ::-1] + n, walls])


def clean(character=None) -> tuple[np.ndarray, np.ndarray]:
    """The character as one closed surface: manifold3d's union of the closed parts and of the open parts thickened
    to SHEET (module docstring)."""
    import manifold3d

    solids = []
    for name, (v, f), closed in character or parts():
        if name == "shirt":  # a filled tube: the torso under it is no part of a clean export either
            r, z0, z1 = SHIRT
            solids.append(manifold3d.Manifold.cylinder(z1 - z0, r, r, 40).translate((0, 0, z0)))
            continue
        if not closed:
            v, f = _thick(v, f, SHEET)
        m = manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v, dtype=np.float64),
                                                  tri_verts=np.ascontiguousarray(f, dtype=np.uint64)))  # fmt: skip
        if m.status() != manifold3d.Error.NoError:
            raise RuntimeError(f"manifold3d refused a part: {m.status()}")
        solids.append(m)
    return _arrays(manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add))
