"""fit/parts.py and fit/visible.outside_surface: the exact outside surface of assets made of parts (issue 55).

The scenes are benchmarks/parts.py's (primitives through each other, a housing, parts face to face, a sheet through
a solid), their truths manifold3d's union computed there from the primitives; distances by that module's
independent measure (trimesh samples, scipy's cKDTree, point-triangle distances)."""

from __future__ import annotations

import numpy as np
import pytest

from tetweave_codec.errors import InputError

trimesh = pytest.importorskip("trimesh")
manifold3d = pytest.importorskip("manifold3d")

from tetweave_codec.benchmarks import parts as scenes  # noqa: E402
from tetweave_codec.fit import visible  # noqa: E402
from tetweave_codec.fit.parts import closed_union, split_parts  # noqa: E402
from tetweave_codec.fit.visible import choose_surface, outside_surface, visible_surface  # noqa: E402
from tetweave_codec.meshio import normalize  # noqa: E402
from tetweave_codec.render.visibility import RESOLUTION, bounding_radius, pixel_size  # noqa: E402


def ball(radius=0.9, centre=(0.0, 0.0, 0.0), subdivisions=2):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, dtype=np.float64) + np.asarray(centre), np.asarray(m.faces, dtype=np.int64)


def closed_and_oriented(v, f) -> bool:
    m = trimesh.Trimesh(v, f, process=False)
    return bool(m.is_watertight and m.is_winding_consistent and m.volume > 0)


def auto(messy):
    """choose_surface(auto) of a mesh in its normalized frame, and the surface back in the input's frame."""
    v, f = messy
    n, scale, offset = normalize(v)
    choice = choose_surface(n, f, "auto")
    s = choice.surface
    return choice, (None if s is None else (s.vertices * scale + offset, s.faces))


def test_components_and_closed_parts():
    a, b = ball(0.5, (-0.6, 0, 0)), ball(0.5, (0.6, 0, 0))
    inverted = (ball(0.2, (0.6, 0, 0))[0], ball(0.2)[1][:, ::-1])
    sheet = (np.array([[-1.0, 1.0, -1.0], [1.0, 1.0, -1.0], [1.0, 1.0, 1.0]]), np.array([[0, 1, 2]]))
    v, f = scenes.join(a, b, inverted, sheet)
    p = split_parts(v, f)
    assert p.count == 4
    assert p.closed.tolist() == [0, 1, 2] and p.inverted.tolist() == [False, False, True]
    assert p.rest.sum() == 1 and p.rest[-1]
    # an inconsistently oriented ball and an unwelded soup of a ball: welded, the soup is closed; the other not
    v2, f2 = ball()
    f2 = f2.copy()
    f2[0] = f2[0][::-1]
    assert split_parts(v2, f2).rest.all()
    soup = (v2[ball()[1]].reshape(-1, 3), np.arange(3 * len(f2)).reshape(-1, 3))
    assert split_parts(*soup).closed.tolist() == [0]


def welded(*meshes):
    """One mesh of `meshes` ((V,3), (F,3)) with vertices at equal positions merged: an assembly exported as one mesh,
    whose parts share the edges and vertices where they touch."""
    v, f = scenes.join(*meshes)
    unique, inverse = np.unique(v, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[f]


def box(size=(1.0, 1.0, 1.0), at=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(size)
    return np.asarray(m.vertices) + np.asarray(at, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def tet(apex):
    v = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], apex, [1.0, 0.0, 0.5]])
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    if np.linalg.det(v[1:] - v[0]) > 0:  # outward: the faces above are outward for a negative determinant
        f = f[:, ::-1]
    return v, f


def test_welded_parts_sharing_edges_are_closed_parts():
    # boxes sharing one edge (4 faces on it), boxes face to face (4 faces on each edge of the contact square), two
    # tets sharing an edge: each part is closed, none is left to the renders
    for meshes in (
        (box(), box(at=(1.0, 1.0, 0.0))),
        (box(), box(at=(1.0, 0.0, 0.0))),
        (tet([0.0, 1.0, 0.5]), tet([-0.7, -0.7, 0.5])),
        (box(), box(at=(1.0, 1.0, 0.0)), box(at=(2.0, 0.0, 0.0)), box(at=(1.0, -1.0, 0.0))),  # a ring around an edge
    ):
        v, f = welded(*meshes)
        p = split_parts(v, f)
        assert p.count == len(meshes) and len(p.closed) == len(meshes) and not p.rest.any(), meshes
        assert not p.inverted.any()
        assert np.bincount(p.component).tolist() == [len(m[1]) for m in meshes]
    # welded boxes sharing an edge go to their exact union (auto), which is their two closed surfaces
    v, f = welded(box(), box(at=(1.0, 1.0, 0.0)))
    u = closed_union(v, f, split_parts(v, f))
    assert np.isclose(u.area, 12.0) and closed_and_oriented(u.vertices, u.faces) is False  # 2 solids, 1 edge shared


def test_welded_parts_that_do_not_alternate_around_an_edge():
    # an inside-out box welded to a box along an edge: around the shared edge the faces do not bound disjoint
    # wedges, so no face is joined across it; each box is still one part through its other edges, closed, the
    # second inside out (turned outwards for the union)
    inside_out = (box(at=(1.0, 1.0, 0.0))[0], box()[1][:, ::-1])
    v, f = welded(box(), inside_out)
    p = split_parts(v, f)
    assert p.closed.tolist() == [0, 1] and p.inverted.tolist() == [False, True] and not p.rest.any()


def test_parts_joined_at_a_vertex_are_two():
    """Two balls whose icosphere vertices coincide where they overlap: welded, they share vertices, not edges."""
    v, f = scenes.join(ball(0.6, (-0.3, 0, 0)), ball(0.6, (0.3, 0, 0)))
    assert len(np.unique(v, axis=0)) < len(v)
    assert split_parts(v, f).closed.tolist() == [0, 1]


def test_union_is_manifold3d_and_keeps_whole_input_faces():
    parts = scenes.cylinders_through_spheres(48)
    v, f = scenes.join(*parts)
    u = closed_union(v, f, split_parts(v, f))
    tv, tf = scenes.union(*parts)
    assert closed_and_oriented(u.vertices, u.faces)
    assert u.area == pytest.approx(trimesh.Trimesh(tv, tf).area, rel=1e-9)
    kept = u.kept >= 0
    assert kept.sum() > len(f) // 2
    assert np.array_equal(u.faces[kept], f[u.kept[kept]])  # the input's own faces and vertices
    again = closed_union(v, f, split_parts(v, f))
    assert np.array_equal(again.faces, u.faces) and np.array_equal(again.vertices, u.vertices)


@pytest.mark.parametrize("kind", ["cyl48", "cyl12", "boxes", "housing", "spot_cyl"])
def test_overlapping_and_nested_parts_take_their_exact_union(kind):
    messy, truth = scenes.build(kind)
    choice, surface = auto(messy)
    assert choice.mode == "visible" and "exact union" in choice.reason and "% of the area dropped" in choice.reason
    assert closed_and_oriented(*surface)
    assert scenes.measure(truth, *surface)["chamfer"] < 1e-4  # the measure's floor: the same surface


def test_hidden_part_leaves_the_outer_mesh_as_it_was():
    outer = ball(0.9, subdivisions=3)
    v, f = scenes.join(outer, ball(0.3, (0.1, 0.0, 0.0)))
    s = outside_surface(v, f)
    assert np.array_equal(s.faces, outer[1]) and np.array_equal(s.vertices, outer[0])


def test_clean_closed_inputs_keep_every_face():
    """One closed part, even with a slot no view sees into; disjoint parts, 1e-4 apart (parts closer than twice
    fit.parts.TOUCH_OFFSET of their size count as face to face)."""
    box = manifold3d.Manifold.cube((1.6, 1.0, 1.0), center=True)
    slot = manifold3d.Manifold.cube((1.2, 0.02, 0.8), center=True).translate((0.3, 0.0, 0.2))
    slotted = scenes._arrays(box - slot)
    choice = choose_surface(normalize(slotted[0])[0], slotted[1], "auto")
    assert choice.mode == "all" and choice.reason == "a consistently oriented surface, one closed part"
    disjoint = scenes.join(ball(0.4, (-0.5, 0, 0)), ball(0.4, (0.5, 0, 0)), ball(0.1, (0, 0.8, 0)))
    assert auto(disjoint)[0].mode == "all"
    box = scenes._arrays(manifold3d.Manifold.cube((1.0, 1.0, 1.0)))
    near = scenes.join(box, (box[0] + (1.0 + 1e-4, 0.3, 0.0), box[1]))
    choice = auto(near)[0]
    assert choice.mode == "all" and "disjoint or touching" in choice.reason


def test_parts_face_to_face_lose_their_contact():
    """manifold3d's union keeps coincident opposite faces (its symbolic perturbation): the union of the parts
    moved out by 1e-6 drops them."""
    messy, truth = scenes.build("touching")
    choice, surface = auto(messy)
    assert choice.mode == "visible" and "exact union" in choice.reason
    assert closed_and_oriented(*surface)
    assert scenes.measure(truth, *surface)["chamfer"] < 1e-5


def test_sheet_through_a_solid_loses_the_inside_and_keeps_the_rest(monkeypatch):
    """The square's pieces inside spot drop out, the rest is kept (exactly the truth, open) and made a closed slab
    SHEET_THICKNESS thick behind it (the winding number is 1 in its middle, 0 a little above and below it)."""
    from tetweave_codec.fit.initialize import signed_distance

    messy, truth = scenes.build("sheet")
    choice, surface = auto(messy)
    assert choice.mode == "visible" and "other faces" in choice.reason
    assert scenes.measure(truth, *surface)["chamfer"] < 2.5e-3  # the slab's back, SHEET_THICKNESS off
    n, scale, offset = normalize(messy[0])
    y = (messy[0][-1, 1] - offset[1]) / scale
    s = choice.surface
    half = 0.5 * visible.SHEET_THICKNESS
    probes = np.array([[0.85, y + d, 0.85] for d in (-half, half, -0.02, 0.02)])
    sd = signed_distance(probes, s.vertices, s.faces)
    assert min(sd[0], sd[1]) < 0 < min(sd[2], sd[3])  # inside the slab on one side of the sheet, outside beyond
    monkeypatch.setattr(visible, "SHEET_THICKNESS", 0.0)
    _, sheet = auto(messy)
    assert scenes.measure(truth, *sheet)["chamfer"] < 1e-4


def test_long_faces_are_split_to_a_pixel_at_seams():
    """Without closed parts (every face of the scene reversed at random: renders decide), the pieces of the two
    triangles per side left inside another box are at most a few pixels deep (where the seam meets the other
    box's edge) and a small share of the area more than a pixel deep."""
    from tetweave_codec.fit.initialize import signed_distance
    from tetweave_codec.geometry.triangles import face_areas

    v, clean = scenes.join(*scenes.boxes())
    flip = np.random.default_rng(0).random(len(clean)) < 0.5
    f = clean.copy()
    f[flip] = f[flip][:, ::-1]
    n, _, _ = normalize(v)
    assert not len(split_parts(n, f).closed)
    s = visible_surface(n, f)
    pixel = pixel_size(RESOLUTION, bounding_radius(n, f))
    centroids = s.vertices[s.faces].mean(axis=1)
    depth = np.max([-signed_distance(centroids, n, clean[o : o + 12]) for o in (0, 12, 24)], axis=0)
    area = face_areas(s.vertices, s.faces)
    print(depth.max() / pixel, area[depth > pixel].sum() / area.sum())
    assert depth.max() < 3 * pixel
    assert area[depth > pixel].sum() < 1e-3 * area.sum()
    assert s.refined > 10 * len(f)


def test_refinement_budget_is_one_input_error(monkeypatch):
    monkeypatch.setattr(visible, "MAX_REFINED_FACES", 50)
    v, f = scenes.join(*scenes.boxes())
    f = f.copy()
    f[::2] = f[::2][:, ::-1]
    with pytest.raises(InputError, match="more than .* faces"):
        visible_surface(normalize(v)[0], f)


@pytest.mark.slow
def test_encode_of_boxes_through_boxes_is_as_good_as_their_union():
    """--size 5k, one thread: the messy boxes against the exact union given clean (issue 55's target: <= 1.25x
    the clean error, <= 1 % of the decoded area unseen, closed)."""
    import torch

    from tetweave_codec.encoder import encode

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        messy, truth = scenes.build("boxes")
        clean = encode(*truth, size=5 * 1024, device="cpu")
        res = encode(*messy, size=5 * 1024, device="cpu")
    finally:
        torch.set_num_threads(before)
    assert res.stats["surface"] == "visible"
    m, c = scenes.measure(truth, res.vertices, res.faces), scenes.measure(truth, clean.vertices, clean.faces)
    assert m["chamfer"] <= 1.25 * c["chamfer"]
    assert m["unseen"] <= 0.01 and m["closed"]
    assert abs(m["nc"] - c["nc"]) <= 0.01


def _shell(radius, inward=False, centre=(0.0, 0.0, 0.0)):
    v, f = ball(radius, centre)
    return v, (f[:, ::-1] if inward else f)


def test_outer_shells_drop_sealed_cavities_and_what_lies_in_them():
    from tetweave_codec.fit.parts import outer_shells

    # a hollow ball (outer shell + inward cavity shell) with a ball floating in the cavity, and a ball beside it
    v, f = scenes.join(_shell(0.8), _shell(0.6, inward=True), _shell(0.3), _shell(0.2, centre=(1.5, 0.0, 0.0)))
    keep = outer_shells(v, f)
    sizes = [len(ball()[1])] * 4
    expect = np.repeat([True, False, False, True], sizes)
    assert np.array_equal(keep, expect)
    assert outer_shells(*_shell(0.5)).all()


@pytest.mark.parametrize("name", ["gearbox", "bolted", "booleans", "enclosure"])
def test_welded_cad_assemblies_are_closed_parts_and_their_union_is_the_kernels(name):
    """The CAD assemblies of benchmarks/assets exported as one welded mesh (parts sharing edges, coincident contact
    faces, sealed clearances): every part is a closed part, and the exact union with its cavities dropped is the
    CAD kernel's own fused outer shell, measured by the independent judge (benchmarks/assets/judge.py)."""
    from tetweave_codec.benchmarks import assets
    from tetweave_codec.benchmarks.assets import judge

    asset = assets.load(name)
    v, f = asset.parts.welded()
    n, scale, offset = normalize(v)
    p = split_parts(n, f)
    assert len(p.closed) == p.count and not p.rest.any()
    choice = choose_surface(n, f, "auto")
    assert choice.mode == "visible" and "the exact union of" in choice.reason
    target = (choice.surface.vertices * scale + offset, choice.surface.faces)
    assert closed_and_oriented(*target)
    assert judge.chamfer(judge.truth_of(asset), *target)["chamfer"] < 2e-5  # the judge's floor is ~3e-6


def test_hostile_part_configurations_choose_quickly():
    """Issue 59's bad inputs, as auto sees them: two identical parts on top of each other (one part, the copy's
    faces duplicates: their union), parts nested ten deep (the outer box), a part inside out inside another (the
    outer one): closed surfaces at once, no renders."""
    twins = scenes.join(box(), box())
    nested = scenes.join(*[box((1.0 + 0.1 * k,) * 3) for k in range(10)])
    inner = box((0.5, 0.5, 0.5))
    inside_out = scenes.join(box(), (inner[0], inner[1][:, ::-1]))
    for messy, parts, kept in ((twins, 1, 12), (nested, 10, 12), (inside_out, 2, 12)):
        p = split_parts(*messy)
        assert len(p.closed) == parts and not p.rest.any()
        choice, surface = auto(messy)
        assert choice.mode == "visible" and f"the exact union of {parts} closed part" in choice.reason
        assert len(surface[1]) == kept and closed_and_oriented(*surface)
    p = split_parts(*twins)
    assert p.duplicate.sum() == 12 and p.duplicate[12:].all()
