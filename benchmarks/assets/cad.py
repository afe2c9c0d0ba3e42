"""CAD assemblies built with a real kernel (build123d on OpenCascade, the `cad` extra), and their truths.

Each generator returns its parts as named solids, in millimetres, placed as an assembly places them (never
booleaned): parts pass through each other, touch face to face, share edges, sit inside a closed housing. OCCT's
tessellation of each part (`tessellate`) gives what real exports hold: long thin triangles on planar faces with
holes, circles as inscribed polygons whose vertices differ between parts that share a cylinder.

The truth is the kernel's own: the boolean fuse of all solids (exact B-rep geometry, coincident faces and
cylinders resolved exactly), each resulting solid's OUTER shell only (a void sealed inside, such as a housing's
cavity or the gap around a bolt between head and nut, is no part of what a viewer sees), tessellated with the same
tolerances. Nothing here uses tetweave_codec.

    gearbox()     a housing (box cup + lid) sealed by two bearings per shaft, two shafts through them, three gears
    bolted()      a plate with six clearance holes, four bolts (hex head + shank) through them with nuts, a
                  washer, one bolt-less hole, a bracket on the plate
    booleans()    25 boxes, cylinders, boxes with holes, long bars and rotated boxes through each other, some
                  sharing faces or edges exactly
    enclosure()   a box with a lid and screws, a board on standoffs inside with chips, capacitors and a connector
                  (all hidden), a lens through the lid, feet
"""

from __future__ import annotations

import math

import numpy as np

from tetweave_codec.benchmarks.assets.meshes import weld

# OCCT tessellation: linear deflection (mm) and angular deflection (radians); coarse on purpose (real exports of
# assemblies are), and small committed files.
TOLERANCE = 0.25
ANGULAR = 0.5


def _b():
    import build123d

    return build123d


def gear(teeth: int, root: float, tip: float, thickness: float, bore: float, phase: float = 0.0):
    """A spur gear (trapezoid teeth between radii root and tip), `thickness` along z centred on z = 0, with a bore."""
    b = _b()
    pts = []
    for k in range(teeth):
        a = 2 * math.pi * (k + phase) / teeth
        w = 2 * math.pi / teeth
        for da, r in ((-0.30, root), (-0.16, tip), (0.16, tip), (0.30, root)):
            pts.append((r * math.cos(a + da * w), r * math.sin(a + da * w)))
    profile = b.Polygon(*pts, align=None)
    body = b.Pos(0, 0, -thickness / 2) * b.extrude(profile, amount=thickness)
    return body - b.Cylinder(bore, 2 * thickness)


def _along_x(shape, x: float = 0.0, y: float = 0.0, z: float = 0.0):
    b = _b()
    return b.Pos(x, y, z) * (b.Rot(0, 90, 0) * shape)


def gearbox():
    """[(name, solid)]: a housing cup 140 x 110 x 80 (walls 5) with a lid 6 thick on it (same footprint: their
    outer edges coincide), two shafts (radius 6) along x through bearings (rings 6..11, flange 1 mm outside) that
    fill the wall holes exactly, three gears on the shafts (bores = shaft radius), the lid's four bolt heads."""
    b = _b()
    lx, ly, lz, wall = 140.0, 110.0, 80.0, 5.0
    cup = b.Pos(0, 0, lz / 2) * b.Box(lx, ly, lz) - b.Pos(0, 0, lz / 2 + wall) * b.Box(lx - 2 * wall, ly - 2 * wall, lz)
    lid = b.Pos(0, 0, lz + 3) * b.Box(lx, ly, 6)
    parts = [("cup", None), ("lid", lid)]
    shafts = [(-18.0, 40.0), (22.0, 40.0)]
    for y, z in shafts:
        hole = _along_x(b.Cylinder(11, lx + 20), 0, y, z)
        cup = cup - hole
    parts[0] = ("cup", cup)
    for i, (y, z) in enumerate(shafts):
        parts.append((f"shaft{i}", _along_x(b.Cylinder(6, lx + 40), 0, y, z)))
        for side in (-1, 1):
            # ring from 4 mm inside the cavity to 1 mm outside the wall, bore = shaft, outer = wall hole
            x0 = side * (lx / 2 - wall - 4)
            x1 = side * (lx / 2 + 1)
            length = abs(x1 - x0)
            ring = b.Cylinder(11, length) - b.Cylinder(6, 2 * length)
            parts.append((f"bearing{i}{'lr'[side > 0]}", _along_x(ring, 0.5 * (x0 + x1), y, z)))
    parts.append(("gear_a", _along_x(gear(18, 20.5, 26.0, 12, 6), 0, -18, 40)))
    parts.append(("gear_b", _along_x(gear(12, 12.5, 18.0, 12, 6, phase=0.5), 0, 22, 40)))
    parts.append(("gear_c", _along_x(gear(10, 10.0, 14.0, 8, 6), -35, -18, 40)))
    for i, (x, y) in enumerate([(-60, -45), (60, -45), (-60, 45), (60, 45)]):
        parts.append((f"bolt{i}", b.Pos(x, y, lz + 6 + 2) * b.Cylinder(4, 4)))
    return parts


def _hexagon(circumradius: float, height: float):
    b = _b()
    pts = [(circumradius * math.cos(k * math.pi / 3), circumradius * math.sin(k * math.pi / 3)) for k in range(6)]
    return b.Pos(0, 0, -height / 2) * b.extrude(b.Polygon(*pts, align=None), amount=height)


def bolted():
    """[(name, solid)]: a plate 160 x 100 x 10 (z 0..10) with six holes (radius 5.5); four bolts (hex head 6 high
    on the plate's top, shank radius 5 through it) with hex nuts (bore = shank) on its bottom, one under a washer;
    a bolt-less hole; a bracket (an L of two boxes sharing a face) standing on the plate over two bolts."""
    b = _b()
    plate = b.Pos(0, 0, 5) * b.Box(160, 100, 10)
    holes = [(-60, -30), (-60, 30), (0, -30), (0, 30), (60, -30), (60, 30)]
    for x, y in holes:
        plate = plate - b.Pos(x, y, 5) * b.Cylinder(5.5, 30)
    parts = [("plate", plate)]
    for i, (x, y) in enumerate(holes[:4]):
        washer = i == 1
        base = 10 + (2 if washer else 0)
        if washer:
            parts.append(("washer", b.Pos(x, y, 11) * (b.Cylinder(9, 2) - b.Cylinder(5.5, 4))))
        parts.append((f"head{i}", b.Pos(x, y, base + 3) * _hexagon(9, 6)))
        # the shank from inside the head down through the plate and the nut, 4 mm past it
        top, bottom = base + 3, -12
        parts.append((f"shank{i}", b.Pos(x, y, 0.5 * (top + bottom)) * b.Cylinder(5, top - bottom)))
        parts.append((f"nut{i}", b.Pos(x, y, -4) * (_hexagon(9, 8) - b.Cylinder(5, 20))))
    # the bracket: a foot (on the plate) and an upright sharing a face with it
    parts.append(("foot", b.Pos(60, 0, 14) * b.Box(30, 90, 8)))
    parts.append(("upright", b.Pos(71, 0, 38) * b.Box(8, 90, 40)))
    return parts


def booleans():
    """[(name, solid)]: 25 shapes: a row of five cubes (20) face to face, a cube sharing only an edge with its end
    (and a rod along that edge), a tower of three cubes on it with a cap, a plate under the row (face to face),
    boxes with holes, cylinders and long bars (long faces) through the row, boxes turned 45 and 30 degrees through
    others."""
    b = _b()
    parts = []
    for i in range(5):
        parts.append((f"cube{i}", b.Pos(20 * i, 0, 0) * b.Box(20, 20, 20)))
    parts.append(("edge_cube", b.Pos(100, 20, 0) * b.Box(20, 20, 20)))  # shares the edge x=90, y=10 with cube4
    # a rod along that edge (alone the two cubes' union would be non-manifold there)
    parts.append(("edge_rod", b.Pos(90, 10, 0) * b.Cylinder(2, 30)))
    for k in range(3):
        parts.append((f"tower{k}", b.Pos(40, 0, 20 * (k + 1)) * b.Box(20, 20, 20)))
    parts.append(("plate", b.Pos(40, 10, -11) * b.Box(140, 60, 2)))  # under the row, face to face
    for k, x in enumerate((0, 80)):
        ring = b.Box(30, 30, 12) - b.Cylinder(8, 40)
        parts.append((f"holed{k}", b.Pos(x, 0, 16) * ring))
    parts.append(("holed_side", b.Pos(120, 20, 0) * (b.Box(20, 20, 20) - _along_x(b.Cylinder(5, 40)))))
    parts.append(("bar_x", b.Pos(40, 6, 6) * b.Box(220, 4, 4)))
    parts.append(("bar_y", b.Pos(20, 0, 5) * (b.Rot(90, 0, 0) * b.Box(3, 3, 120))))
    parts.append(("bar_z", b.Pos(60, -5, 20) * b.Box(3, 3, 90)))
    for k, x in enumerate((10, 50, 90)):
        parts.append((f"pin{k}", b.Pos(x, 0, 0) * (b.Rot(90, 0, 0) * b.Cylinder(4, 50))))
    parts.append(("rod_z", b.Pos(30, 8, 10) * b.Cylinder(3, 70)))
    parts.append(("turned45", b.Pos(80, 0, 10) * (b.Rot(0, 0, 45) * b.Box(40, 8, 8))))
    parts.append(("turned30", b.Pos(-5, 5, 5) * (b.Rot(30, 0, 20) * b.Box(25, 12, 6))))
    parts.append(("slab", b.Pos(130, -5, 0) * b.Box(10, 50, 30)))  # through holed_side's end
    parts.append(("cap", b.Pos(40, 0, 71) * b.Box(26, 26, 2)))  # on the tower's top, face to face
    return parts


def enclosure():
    """[(name, solid)]: a box 120 x 80 x 40 (walls 3, open top) with a lid 3 thick on it, four screws through the
    lid into bosses, a board (1.6) on four standoffs inside with six chips, three capacitors and a connector (all
    hidden), a lens through the lid (filling its hole exactly), four feet under the box."""
    b = _b()
    lx, ly, lz, wall = 120.0, 80.0, 40.0, 3.0
    box = b.Pos(0, 0, lz / 2) * b.Box(lx, ly, lz) - b.Pos(0, 0, lz / 2 + wall) * b.Box(lx - 2 * wall, ly - 2 * wall, lz)
    lid = b.Pos(0, 0, lz + 1.5) * b.Box(lx, ly, 3)
    lid = lid - b.Pos(30, 20, lz + 1.5) * b.Cylinder(4, 10)
    parts = [("box", box), ("lid", lid)]
    corners = [(-52, -32), (52, -32), (-52, 32), (52, 32)]
    for i, (x, y) in enumerate(corners):
        parts.append((f"boss{i}", b.Pos(x, y, wall + (lz - wall) / 2) * b.Cylinder(4, lz - wall)))
        parts.append((f"screw{i}", b.Pos(x, y, lz + 3 + 1.5) * b.Cylinder(3.5, 3)))
        parts.append((f"foot{i}", b.Pos(x, y, -2) * b.Cylinder(5, 4)))
    for i, (x, y) in enumerate([(-40, -22), (40, -22), (-40, 22), (40, 22)]):
        parts.append((f"standoff{i}", b.Pos(x, y, wall + 4) * b.Cylinder(2.5, 8)))
    board_z = wall + 8 + 0.8
    parts.append(("board", b.Pos(0, 0, board_z) * b.Box(100, 60, 1.6)))
    top = board_z + 0.8
    for i in range(6):
        x, y = -30 + 15 * (i % 3) * 2, -12 + 24 * (i // 3)
        parts.append((f"chip{i}", b.Pos(x, y, top + 1) * b.Box(10, 10, 2)))
    for i, x in enumerate((-10, 0, 10)):
        parts.append((f"cap{i}", b.Pos(x, 0, top + 5) * b.Cylinder(4, 10)))
    parts.append(("connector", b.Pos(-50 + 6 - 0.0, 0, top + 4) * b.Box(12, 14, 8)))
    parts.append(("lens", b.Pos(30, 20, lz + 2.5) * b.Cylinder(4, 5)))
    return parts


GENERATORS = {"gearbox": gearbox, "bolted": bolted, "booleans": booleans, "enclosure": enclosure}


def tessellate(shape, tolerance: float = TOLERANCE, angular: float = ANGULAR) -> tuple[np.ndarray, np.ndarray]:
    """OCCT's tessellation of a shape: (vertices (V,3) float64, faces (F,3) int64), turned so that its signed
    volume is positive (outward) when it is closed."""
    verts, tris = shape.tessellate(tolerance, angular)
    v = np.array([[p.X, p.Y, p.Z] for p in verts], dtype=np.float64)
    f = np.array(tris, dtype=np.int64).reshape(-1, 3)
    a, bb, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(bb, c)).sum() < 0:
        f = f[:, ::-1]
    return v, f


def parts_meshes(parts) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each part's solid tessellated on its own (what an exporter writes per part)."""
    return [tessellate(solid) for _, solid in parts]


def truth(parts) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's outside surface: the fuse of all solids, each resulting solid's outer shell, tessellated."""
    from OCP.BRepClass3d import BRepClass3d

    b = _b()
    solids = [s for _, s in parts]
    fused = solids[0].fuse(*solids[1:]).clean()
    meshes = []
    for solid in fused.solids():
        shell = b.Shell(BRepClass3d.OuterShell_s(solid.wrapped))
        meshes.append(tessellate(shell))
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    v = np.concatenate([v for v, _ in meshes]).astype(np.float32).astype(np.float64)
    # OCCT meshes each B-rep face on its own: its vertices on shared edges are equal, welded here (a closed mesh)
    return weld(v, np.concatenate([f + o for (_, f), o in zip(meshes, offsets[:-1], strict=True)]))
