"""The encoder's self-check acting (encoder._checked) and the default fit's size on an outside surface
(encoder.target_faces): issue 59, items 2-3. No fit here: EncodeResults are built from meshes whose hidden share
is known (a box with a box inside it: the inner box's area is hidden from every outside view)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from tetweave_codec import encoder  # noqa: E402
from tetweave_codec.job import EncodeResult  # noqa: E402
from tetweave_codec.metrics.unseen import WARN_SHARE, unseen_area_share  # noqa: E402


def _box(extent, at=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extent)
    return np.asarray(m.vertices) + np.asarray(at), np.asarray(m.faces, dtype=np.int64)


def _result(meshes, surface="all", reason="closed and open parts"):
    vs, fs, n = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + n)
        n += len(v)
    prepared = SimpleNamespace(outside_differs=True)
    stats = {"surface": surface, "surface_reason": reason}
    return EncodeResult(b"", np.concatenate(vs), np.concatenate(fs), stats, prepared)


def test_hidden_decode_tries_the_outside_surface_and_keeps_the_less_hidden():
    membrane = _result([_box((1.6, 1.6, 1.6)), _box((1.0, 1.0, 1.0))])
    assert unseen_area_share(membrane.vertices, membrane.faces) > WARN_SHARE
    clean = _result([_box((1.6, 1.6, 1.6))], surface="visible", reason="the exact union of 2 closed parts")
    calls = []

    def outside():
        calls.append(1)
        return clean

    kept = encoder._checked(membrane, outside)
    assert kept is clean and calls == [1]
    assert "kept the outside surface" in kept.stats["surface_reason"]
    assert kept.stats["surface_reason"].startswith("the exact union of 2 closed parts; the self-check found")
    # the other way round: the outside surface's decode is the more hidden one, so every face stays
    kept = encoder._checked(membrane, lambda: _result([_box((1.6, 1.6, 1.6)), _box((1.2, 1.2, 1.2))], "visible"))
    assert kept is membrane and "kept every face" in kept.stats["surface_reason"]


def test_a_decode_seen_from_outside_is_kept_without_a_second_encode():
    seen = _result([_box((1.6, 1.6, 1.6))])

    def outside():
        raise AssertionError("no second encode when the self-check finds nothing hidden")

    assert encoder._checked(seen, outside) is seen
    assert seen.stats["surface_reason"] == "closed and open parts"


def test_default_size_follows_the_outside_surface_at_most_the_input():
    surface = SimpleNamespace(faces=np.zeros((300, 3), dtype=np.int64))
    assert encoder.target_faces(surface, 1000) == 300  # hidden parts dropped: sized as the surface alone
    assert encoder.target_faces(surface, 200) == 200  # cut seams and pixel pieces are not detail
    assert encoder.default_points(encoder.target_faces(surface, 1000), 1) == encoder.default_points(300, 1)
