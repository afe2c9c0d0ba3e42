"""Holes kept open (`tetweave encode --holes keep`): the holes section's coding, the decoder's removal and its
checks, the encoder's choice of cap faces, and hostile holes sections."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode, decode_detailed
from tetweave_codec.encoder import encode
from tetweave_codec.errors import ContainerError
from tetweave_codec.fit.holes import cap_faces, hole_ranks, input_rim
from tetweave_codec.formats import holes as H
from tetweave_codec.formats import tw
from tetweave_codec.formats.common import FLAG_HOLES
from tetweave_codec.geometry.holes import face_ranks, open_holes, pinched_vertices, without_pinches
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.subdivision import loop_subdivide
from tetweave_codec.meshio import save_mesh
from tetweave_codec.metrics import chamfer_distance, topology

manifold3d = pytest.importorskip("manifold3d")

FAST = {"points": 1024, "sh_degree": 0, "quality": "fast", "iters": 40, "device": "cpu", "seed": 0}


def _mesh(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def octahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]], dtype=np.int64
    )
    return v, f


def cut_sphere(z_cut: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere without its faces above z_cut: open, one boundary loop of radius ~sqrt(1 - z_cut^2)."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 48))
    return v, f[v[f].mean(1)[:, 2] < z_cut]


# ---------------------------------------------------------------------------------------------------------
# the section's coding


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=300, unique=True))
def test_holes_section_round_trips(values):
    ranks = np.sort(np.array(values, dtype=np.int64))
    np.testing.assert_array_equal(H.decode_holes(H.encode_holes(ranks), 10), ranks)


def test_holes_section_writer_rejects_what_a_reader_would():
    for bad in ([], [3, 3], [5, 2], [-1], [2**32]):
        with pytest.raises(ValueError):
            H.encode_holes(np.array(bad, dtype=np.int64))


def test_holes_section_reader_bounds_and_rejects():
    good = H.encode_holes(np.array([1, 5, 9]))
    with pytest.raises(ContainerError, match="truncated"):
        H.decode_holes(good[:3], 10)
    for k in (0, H.max_hole_faces(10) + 1, 2**32 - 1):  # K is bounded before anything is allocated
        bad = k.to_bytes(4, "little") + good[4:]
        with pytest.raises(ContainerError, match="hole faces"):
            H.decode_holes(bad, 10)
    # Random bytes and bit flips of valid sections: a ContainerError or some strictly increasing ranks in range,
    # nothing else. Random bytes alone are always rejected (their K is out of range), so the valid
    # sections' flips are what reaches the checks; both outcomes are counted and must occur.
    rng = np.random.default_rng(0)
    outcomes = {"rejected": 0, "decoded": 0}
    for trial in range(300):
        if trial % 2:
            blob = bytes(rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8))
        else:
            ranks = np.sort(rng.choice(50, size=int(rng.integers(1, 20)), replace=False))
            blob = bytearray(H.encode_holes(ranks))
            for _ in range(int(rng.integers(1, 4))):
                blob[int(rng.integers(len(blob)))] ^= 1 << int(rng.integers(8))
            blob = bytes(blob)
        try:
            r = H.decode_holes(blob, 50)
        except ContainerError:
            outcomes["rejected"] += 1
            continue
        assert len(r) >= 1 and np.all(np.diff(r) > 0) and r[0] >= 0 and r[-1] <= H.MAX_RANK
        outcomes["decoded"] += 1
    assert outcomes["rejected"] > 0 and outcomes["decoded"] > 0, outcomes


# ---------------------------------------------------------------------------------------------------------
# the decoder's removal


def test_face_ranks_do_not_depend_on_face_order_or_rotation():
    v, f = octahedron()
    ranks = face_ranks(f)
    assert sorted(ranks.tolist()) == list(range(len(f)))
    perm = np.random.default_rng(1).permutation(len(f))
    rotated = np.roll(f[perm], 1, axis=1)
    np.testing.assert_array_equal(face_ranks(rotated), ranks[perm])


def test_pinched_vertices():
    bowtie = np.array([[0, 1, 2], [0, 3, 4]])
    assert pinched_vertices(bowtie, 5).tolist() == [0]
    v, f = octahedron()
    assert len(pinched_vertices(f, 6)) == 0
    assert len(pinched_vertices(f[1:], 6)) == 0  # one face off: a boundary, no pinch
    # two opposite faces around vertex 4 off: its remaining faces form two fans
    assert pinched_vertices(f[[1, 3, 4, 5, 6, 7]], 6).tolist() == [4]


def test_open_holes_removes_faces_and_their_subdivided_children():
    v, f = octahedron()
    ranks = face_ranks(f)
    drop = np.array([0])  # the face of rank 0
    ov, of = open_holes(v, f, f, drop, 1)
    assert len(of) == 7 and topology(ov, of)["boundary_edges"] == 3
    sv, sf = loop_subdivide(v, f, 1)
    ov, of = open_holes(sv, sf, f, drop, 4)
    assert len(of) == 28 and topology(ov, of)["boundary_edges"] == 6 and topology(ov, of)["nonmanifold_edges"] == 0
    removed_face = int(np.flatnonzero(ranks == 0)[0])
    kept_children = np.delete(sf, np.arange(4 * removed_face, 4 * removed_face + 4), axis=0)
    assert {tuple(sorted(x)) for x in sv[kept_children].round(12).reshape(-1, 9).tolist()} == {
        tuple(sorted(x)) for x in ov[of].round(12).reshape(-1, 9).tolist()
    }


def test_open_holes_rejects_bad_lists():
    v, f = octahedron()
    with pytest.raises(ContainerError, match="rank"):
        open_holes(v, f, f, np.array([8]), 1)
    ranks = face_ranks(f)
    pinch = np.sort(ranks[[0, 2]])  # faces 0 and 2 share only vertex 4
    with pytest.raises(ContainerError, match="two parts"):
        open_holes(v, f, f, pinch, 1)


# ---------------------------------------------------------------------------------------------------------
# the encoder's choice


def test_cap_faces_of_a_closed_surface_over_an_open_input():
    """The sphere's faces above the cut are caps; those below lie on the input."""
    iv, if_ = cut_sphere(0.6)
    rim = input_rim(iv, if_)
    assert rim is not None and input_rim(*octahedron()) is None
    sv, sf = _mesh(manifold3d.Manifold.sphere(1.0, 48))
    cap = cap_faces(rim, sv, sf)
    z = sv[sf].mean(1)[:, 2]
    assert cap[z > 0.62].all() and not cap[z < 0.55].any()
    ranks = hole_ranks(rim, sv, sf)
    assert len(ranks) == cap.sum() and np.all(np.diff(ranks) > 0)


def test_seams_are_not_holes():
    """Duplicated vertices along a seam (as OBJ texture seams make them) do not make a rim."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 32))
    upper = v[f].mean(1)[:, 2] > 0
    split_v = np.concatenate([v, v])  # the upper half's faces use a copy of every vertex
    split_f = np.where(upper[:, None], f + len(v), f)
    assert input_rim(split_v, split_f) is None
    cut = split_f[v[f].mean(1)[:, 2] < 0.6]
    assert input_rim(split_v, cut) is not None


def test_keep_holes_end_to_end():
    """An open input: the file lists the cap faces, the decoder removes them; decode == report, 2-manifold with
    the input's boundary, no self-intersections, deterministic, and closer to the input than the closed file."""
    v, f = cut_sphere(0.6)
    closed = encode(v, f, holes="close", **FAST)
    kept = encode(v, f, holes="keep", **FAST)
    again = encode(v, f, holes="keep", **FAST)
    assert kept.data == again.data
    tw_file = tw.unpack(kept.data)
    assert tw_file.flags & FLAG_HOLES and kept.stats["hole_faces"] == len(tw_file.holes) > 0
    assert 0 < len(kept.data) - len(closed.data) < 200
    dv, df = decode(kept.data)
    np.testing.assert_array_equal(dv, kept.vertices)
    np.testing.assert_array_equal(df, kept.faces)
    topo = topology(dv, df)
    assert topo["two_manifold"] and topo["nonmanifold_edges"] == 0 and topo["boundary_edges"] > 0
    assert not self_intersecting_faces(dv, df).any()
    full = decode_detailed(kept.data)
    assert topology(full.closed_vertices, full.closed_faces)["boundary_edges"] == 0
    # the boundary of the decoded mesh follows the input's rim (z = 0.6 on the unit sphere, radius 0.8)
    edges = np.sort(df[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    rim_z = dv[np.unique(uniq[counts == 1])][:, 2]
    assert abs(np.median(rim_z) - 0.6) < 0.1
    cd_closed = chamfer_distance(v, f, closed.vertices, closed.faces, n_samples=50_000)
    cd_kept = chamfer_distance(v, f, dv, df, n_samples=50_000)
    assert cd_kept < 0.7 * cd_closed


def test_keep_holes_changes_nothing_for_a_closed_input():
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 32))
    a = encode(v, f, holes="close", **FAST)
    b = encode(v, f, holes="keep", **FAST)
    assert a.data == b.data and b.stats["hole_faces"] == 0


def test_hostile_holes_sections_in_real_files():
    """Mutations of a real file's holes section (checksum recomputed): a ContainerError, or an open 2-manifold
    without self-intersections; never anything else."""
    from tetweave_codec.formats.common import seal

    v, f = cut_sphere(0.6)
    data = encode(v, f, holes="keep", **FAST).data
    hsize = tw.unpack(data).sizes["holes"]
    body = bytearray(data[:-4])
    start = len(body) - hsize
    from tetweave_codec.formats.tw2 import pack_v2

    full = decode_detailed(data)
    ranks_of = face_ranks(full.extracted_faces)
    listed = np.isin(ranks_of, tw.unpack(data).holes)
    rng = np.random.default_rng(5)
    # Byte mutations are rejected (60 of 60 when written; so are random subsets of the encoder's list, whose
    # removal pinches), so a quarter of the trials are valid lists other than the encoder's (random halves of it,
    # made pinch-free), which must decode open: both outcomes are counted and must occur.
    outcomes = {"rejected": 0, "open": 0}
    for _ in range(60):
        mutated = bytearray(body)
        kind = rng.integers(4)
        if kind == 0:  # bit flips in the section
            for _ in range(int(rng.integers(1, 6))):
                mutated[start + int(rng.integers(hsize))] ^= 1 << int(rng.integers(8))
        elif kind == 1:  # a random K
            mutated[start : start + 4] = int(rng.integers(0, 2**32)).to_bytes(4, "little")
        elif kind == 2:  # random bytes after K
            mutated[start + 4 :] = bytes(rng.integers(0, 256, hsize - 4, dtype=np.uint8))
        half = without_pinches(full.extracted_faces, listed & (rng.random(len(listed)) < 0.5))
        try:
            if kind == 3:
                if not half.any():
                    continue
                dv, df = decode(pack_v2(replace(tw.unpack(data), holes=np.sort(ranks_of[half]), sizes=None)))
            else:
                dv, df = decode(seal(bytes(mutated)))
        except ContainerError:
            outcomes["rejected"] += 1
            continue
        topo = topology(dv, df)
        assert topo["two_manifold"] and topo["nonmanifold_edges"] == 0
        assert not self_intersecting_faces(dv, df).any()
        outcomes["open"] += 1
    assert outcomes["rejected"] > 0 and outcomes["open"] > 0, outcomes
    # and more such lists, each with the boundary the removal opens
    halves = 0
    for _ in range(5):
        remove = without_pinches(full.extracted_faces, listed & (rng.random(len(listed)) < 0.5))
        if not remove.any():
            continue
        other = pack_v2(replace(tw.unpack(data), holes=np.sort(ranks_of[remove]), sizes=None))
        dv, df = decode(other)
        topo = topology(dv, df)
        assert topo["two_manifold"] and topo["nonmanifold_edges"] == 0 and topo["boundary_edges"] > 0
        halves += 1
    assert halves > 0


def test_pack_requires_flag_and_list_together():
    from tetweave_codec.formats.tw2 import pack_v2, quantize_file

    rng = np.random.default_rng(0)
    pts = rng.normal(scale=0.4, size=(30, 3))
    f, _ = quantize_file(
        pts, np.linalg.norm(pts, axis=1) - 0.5, None, -1, position_bits=10, s_step=1e-3, c_band_steps=[]
    )
    with pytest.raises(ValueError, match="bit 7"):
        pack_v2(replace(f, holes=np.array([1, 2])))
    with pytest.raises(ValueError, match="bit 7"):
        pack_v2(replace(f, flags=f.flags | FLAG_HOLES))
    data = pack_v2(replace(f, flags=f.flags | FLAG_HOLES, holes=np.array([1, 2, 40])))
    back = tw.unpack(data)
    np.testing.assert_array_equal(back.holes, [1, 2, 40])
    assert back.sizes["holes"] > 0 and back.sizes["header"] == tw.unpack(pack_v2(f)).sizes["header"] + 4
    # a file whose flags claim a holes section it does not have is rejected (sizes no longer add up)
    forged = bytearray(pack_v2(f))
    forged[10] |= FLAG_HOLES
    from tetweave_codec.formats.common import seal

    with pytest.raises(ContainerError):
        tw.unpack(seal(bytes(forged[:-4])))


def test_cli_keep_holes(tmp_path):
    v, f = cut_sphere(0.6)
    mesh = tmp_path / "open.ply"
    save_mesh(mesh, v, f)
    out = tmp_path / "open.tw"
    args = ["encode", str(mesh), "-o", str(out), "--holes", "keep", "--points", "1024", "--quality", "fast"]
    args += ["--iters", "40", "--sh-degree", "none", "--device", "cpu"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    assert "holes kept open" in result.output
    info = CliRunner().invoke(main, ["info", str(out)])
    assert info.exit_code == 0 and "holes" in info.output and "faces removed" in info.output


def test_pinches_of_the_subdivided_surface_are_those_of_the_extracted_one():
    """Why the decoder checks the extracted surface: random removals from a sphere, before and after two Loop
    levels, pinch the same (old) vertices."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 12))
    sv, sf = loop_subdivide(v, f, 2)
    rng = np.random.default_rng(3)
    pinched_any = 0
    for _ in range(40):
        remove = rng.random(len(f)) < rng.uniform(0.05, 0.5)
        coarse = pinched_vertices(f[~remove], len(v))
        fine = pinched_vertices(sf[np.repeat(~remove, 16)], len(sv))
        np.testing.assert_array_equal(coarse, fine)
        pinched_any += len(coarse) > 0
    assert pinched_any > 5


def test_keep_holes_with_rate_control():
    """--size counts the holes section: the file is in [0.85 S, S] and lists the caps."""
    v, f = cut_sphere(0.6)
    result = encode(v, f, size=3000, holes="keep", quality="fast", device="cpu", sh_degree=0)
    assert 0.85 * 3000 <= len(result.data) <= 3000
    assert tw.unpack(result.data).flags & FLAG_HOLES and result.stats["hole_faces"] > 0
