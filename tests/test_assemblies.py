"""benchmarks/assets: the assemblies of issue 59 are what they claim (welded exports with edges of four faces,
closed truths, parts that overlap or hide each other), and the independent judge (raycast.py, judge.py) measures
what it should. The committed meshes in tests/data/assemblies are used; the tests that regenerate them need the
CAD kernel and skip without it. One slow test encodes the smallest asset end to end."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
manifold3d = pytest.importorskip("manifold3d")

from tetweave_codec.benchmarks import assets  # noqa: E402
from tetweave_codec.benchmarks.assets import CAD_MISSING, CAD_NAMES, DATA, NAMES, judge, load, raycast  # noqa: E402
from tetweave_codec.benchmarks.assets.meshes import edge_face_counts, read_ply, write_ply  # noqa: E402

OPEN_PARTS = {"shirt", "pupill", "pupilr", "teeth_low", "brim"}


def _closed(v, f) -> bool:
    m = trimesh.Trimesh(v, f, process=False)
    return bool(m.is_watertight and m.is_winding_consistent and m.volume > 0)


def _manifold(v, f):
    m = manifold3d.Manifold(
        manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v), tri_verts=np.ascontiguousarray(f, dtype=np.uint64))
    )
    assert m.status() == manifold3d.Error.NoError
    return m


@pytest.fixture(scope="module")
def loaded():
    return {name: load(name) for name in NAMES}


def test_committed_meshes_are_small():
    files = sorted(DATA.glob("*.ply"))
    assert {f.name for f in files} == {f"{n}_parts.ply" for n in NAMES} | {f"{n}_truth.ply" for n in CAD_NAMES}
    assert sum(f.stat().st_size for f in files) < 300 * 1024


@pytest.mark.parametrize("name", NAMES)
def test_welded_export_shares_edges_between_parts(loaded, name):
    """The one-mesh export merges vertices across parts: edges with four faces (two parts meeting there); the
    separate export has none (each part on its own is a 2-manifold, with boundary where open)."""
    a = loaded[name]
    wv, wf = a.parts.welded()
    assert len(wv) < len(a.parts.vertices)
    assert (edge_face_counts(wf) == 4).sum() >= 4
    assert edge_face_counts(a.parts.separate()[1]).max() <= 2


@pytest.mark.parametrize("name", NAMES)
def test_parts_closed_or_open_as_claimed(loaded, name):
    a = loaded[name]
    assert len(a.parts.names) == int(a.parts.part.max()) + 1 >= 15
    for part, (v, f) in zip(a.parts.names, a.parts.part_meshes(), strict=True):
        assert _closed(v, f) == (part not in OPEN_PARTS), part


@pytest.mark.parametrize("name", NAMES)
def test_truth_is_closed_and_watertight(loaded, name):
    """The CAD truths (the kernel's fused outer shells) and every clean input are closed, consistently oriented
    2-manifolds that manifold3d accepts, without a void inside (one shell per solid)."""
    v, f = loaded[name].clean
    assert _closed(v, f)
    m = _manifold(v, f)
    assert m.volume() > 0
    # no inner shell: every connected component bounds positive volume (a void would be inside out); the
    # character's pupils and lower teeth float just off the eyes and the head (disjoint components)
    for piece in m.decompose():
        assert piece.volume() > 0


@pytest.mark.parametrize("name", NAMES)
def test_parts_overlap(loaded, name):
    """The closed parts touch face to face (lids, bearings in holes, gears on shafts: the union, manifold3d here
    from the parts, drops the contact faces: less area than their sum) and, but in the gearbox and the enclosure
    (whose parts only touch), pass through each other (less volume than their sum)."""
    a = loaded[name]
    closed = [_manifold(v, f) for part, (v, f) in zip(a.parts.names, a.parts.part_meshes(), strict=True)
              if part not in OPEN_PARTS]  # fmt: skip
    union = manifold3d.Manifold.batch_boolean(closed, manifold3d.OpType.Add)
    assert union.surface_area() < 0.95 * sum(m.surface_area() for m in closed)
    if name not in ("gearbox", "enclosure"):
        assert union.volume() < 0.999 * sum(m.volume() for m in closed)


def test_hidden_internals(loaded):
    """The housings hide their internals: most of the gearbox's and the enclosure's area, and the body under the
    character's shirt, is seen by no outside ray; the truths drop the sealed cavities (smaller area)."""
    for name, least in (("gearbox", 0.4), ("enclosure", 0.4), ("character", 0.05)):
        v, f = loaded[name].parts.separate()
        _, _, seen = raycast.visible_samples(v, f, 3000, seed=1)
        assert 1.0 - seen.mean() > least, name
    for name in ("gearbox", "enclosure", "bolted"):
        a = loaded[name]
        area = trimesh.Trimesh(*a.truth, process=False).area
        assert area < 0.8 * trimesh.Trimesh(*a.parts.separate(), process=False).area


def test_cad_truth_is_what_rays_see():
    """Two independent truths agree: the kernel's fused outer shell (bolted) and the ray-cast visible samples of
    its parts. Visible samples of the parts lie on the truth, samples of the truth on the parts (within the
    tessellations' difference)."""
    a = load("bolted")
    t = judge.truth_of(a)
    v = (a.parts.vertices - t.centre) * t.scale
    pts, _, _ = raycast.visible_samples(v, a.parts.faces, 4000, seed=2)
    assert np.quantile(judge.distances(pts, t.vertices, t.faces), 0.99) < 2e-3
    assert np.quantile(judge.distances(t.points[:4000], v, a.parts.faces), 0.99) < 2e-3


def test_raycast_nested_spheres():
    """A sphere inside a sphere: the inner one hidden (a fifth of the area), an open bowl seen from both sides."""
    big = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    small = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    v = np.concatenate([big.vertices, small.vertices])
    f = np.concatenate([big.faces, small.faces + len(big.vertices)])
    pts, face, seen = raycast.visible_samples(v, f, 4000)
    assert len(pts) == seen.sum() and (face < len(big.faces)).all()  # no point of the inner sphere seen
    assert abs((1 - seen.mean()) - 0.2) < 0.03
    bowl = big.faces[big.triangles_center[:, 2] < 0.0]
    assert raycast.visible_samples(big.vertices, bowl, 2000)[2].all()


def test_judge_zero_on_truth_and_positive_off_it(loaded):
    a = loaded["booleans"]
    t = judge.truth_of(a)
    assert judge.chamfer(t, *a.truth)["chamfer"] < 2e-5
    scale = 1.0 + 5e-3 / 1.8  # every point moved about 1e-3 (normalized) at the box's extent
    moved = (a.truth[0] - t.centre) * scale + t.centre
    assert judge.chamfer(t, moved, a.truth[1])["chamfer"] > 1e-4
    assert judge.hidden_share(*a.truth, n=2000) < 0.01
    assert judge.closed(*a.truth) and not judge.closed(*a.parts.welded())


def test_ply_roundtrip(tmp_path, loaded):
    a = loaded["booleans"].parts
    write_ply(tmp_path / "x.ply", a.vertices, a.faces, a.part, tuple(f"part {n}" for n in a.names))
    b = read_ply(tmp_path / "x.ply")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.part, b.part) and a.names == b.names
    # other readers read it too
    m = trimesh.load(tmp_path / "x.ply", process=False)
    assert len(m.faces) == len(a.faces)


def _need_cad():
    if not assets.have_cad():
        pytest.skip(CAD_MISSING)


@pytest.mark.parametrize("name", ["bolted", "booleans"])
def test_generators_match_committed_meshes(loaded, name):
    """With the CAD kernel: a fresh generation has the committed parts and truth (same parts, areas within 1e-4;
    OCCT versions may tessellate slightly differently)."""
    _need_cad()
    parts, truth = assets.generate(name)
    a = loaded[name]
    assert parts.names == a.parts.names
    for fresh, stored in ((parts.separate(), a.parts.separate()), (truth, a.truth)):
        fa = trimesh.Trimesh(*fresh, process=False).area
        assert abs(fa / trimesh.Trimesh(*stored, process=False).area - 1) < 1e-4


def test_cad_missing_message(monkeypatch):
    """Without build123d, generating a CAD asset says which extra to install."""
    monkeypatch.setattr(assets, "have_cad", lambda: False)
    with pytest.raises(ImportError, match=r"pip install 'tetweave\[cad\]'"):
        assets.generate("gearbox")


@pytest.mark.slow
def test_encode_smallest_asset_end_to_end(loaded):
    """booleans (1,064 faces) as one welded mesh at --size 5k: the file fits, the decoded mesh is closed, near the
    kernel's truth by the judge, little of it hidden. Regression bounds, not issue 59's target (an error at most
    1.25x the clean truth's encode, 1.32e-3: about 1.65e-3): docs/measurements/assemblies.md has 2.66e-3 and
    3.4 % hidden at the time of writing."""
    from tetweave_codec.encoder import encode
    from tetweave_codec.options import EncodeOptions

    a = loaded["booleans"]
    res = encode(*a.parts.welded(), options=EncodeOptions(size=5 * 1024, threads=1))
    assert len(res.data) <= 5 * 1024
    t = judge.truth_of(a)
    assert judge.closed(res.vertices, res.faces)
    assert judge.chamfer(t, res.vertices, res.faces)["chamfer"] < 4e-3
    assert judge.hidden_share(res.vertices, res.faces, n=4000) < 0.06
