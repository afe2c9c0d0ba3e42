"""One prepared input per encode: the creases are detected and the input's AABB tree is built once, whatever the
number of fits, and the prepared Chamfer distance is exactly the metrics' one."""

from __future__ import annotations

import numpy as np
import pytest

from tetweave_codec.encoder import encode
from tetweave_codec.fit.prepared import prepare_input
from tetweave_codec.metrics import chamfer_distance

manifold3d = pytest.importorskip("manifold3d")

FAST = {"quality": "fast", "iters": 30, "device": "cpu", "seed": 0}


def _mesh(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def csg_part() -> tuple[np.ndarray, np.ndarray]:
    box = manifold3d.Manifold.cube((2.0, 1.4, 1.0), center=True)
    return _mesh(box - manifold3d.Manifold.sphere(0.8, 48).translate((1.0, 0.7, 0.5)))


def test_prepared_chamfer_is_the_metrics_chamfer():
    """Same samples, same trees: the prepared input's Chamfer distance of a mesh in the input's own frame equals
    `metrics.chamfer_distance` bit for bit, for any sample count, and asking twice reuses the reference."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 32))
    v = v * 3.0 + np.array([10.0, -2.0, 0.5])
    other = v * 1.01 + 0.002
    prepared = prepare_input(v, f, seed=7)
    for n in (2_000, 5_000, 2_000):
        assert prepared.chamfer(other, f, n) == chamfer_distance(v, f, other, f, n, seed=7)
    assert len(prepared._references) == 2


def test_one_preparation_per_encode(monkeypatch):
    """A --size encode of a CAD part (crease detection for the defaults, the prior, the feature start; one fit,
    18 candidate packs, the report's Chamfer distance) detects the creases once and builds one AABB tree of the
    input; a --max-error encode with several Chamfer estimates too."""
    import tetweave_codec.fit.initialize as initialize
    import tetweave_codec.fit.prepared as prepared_module
    from tetweave_codec.geometry import closest

    v, f = csg_part()
    detections = []
    real_detect = prepared_module.detect_features
    monkeypatch.setattr(prepared_module, "detect_features", lambda *a: detections.append(1) or real_detect(*a))
    monkeypatch.setattr(initialize, "detect_features", lambda *a: pytest.fail("creases detected again"))
    input_trees = []
    real_init = closest.SurfaceTree.__init__

    def counting_init(self, vertices, faces):
        real_init(self, vertices, faces)
        if np.shares_memory(self.faces, f):  # a tree of the input's own faces (decoded meshes have others)
            input_trees.append(1)

    monkeypatch.setattr(closest.SurfaceTree, "__init__", counting_init)
    result = encode(v, f, size=2500, **FAST)
    assert result.stats["chamfer"] is not None
    assert len(detections) == 1 and len(input_trees) == 1
    detections.clear()
    input_trees.clear()
    result = encode(v, f, max_error=6e-3, **FAST)
    assert result.stats["chamfer"] <= 6e-3
    assert len(detections) == 1 and len(input_trees) == 1


@pytest.mark.parametrize(
    "options,needle",
    [
        ({"size": 5000, "max_error": 1e-3}, "either"),
        ({"layout": "grid", "s_step": 1e-3}, "chooses its own quantization"),
        ({"points": 10}, "points must be"),
        ({"holes": "keep", "format_version": 1}, "version 2"),
        ({"sh_degree": "7"}, "SH degree"),
        ({"layout": "best", "points": 2048}, "best layout"),
    ],
)
def test_options_are_validated_when_made(options, needle):
    """EncodeOptions refuses what no encode can run, in one line, before any mesh is loaded."""
    from tetweave_codec.errors import InputError
    from tetweave_codec.options import EncodeOptions

    with pytest.raises(InputError, match=needle) as info:
        EncodeOptions(**options)
    assert "\n" not in str(info.value)


def test_options_object_runs_the_keyword_encode():
    """encode(options=...) is encode(**options.encoder_kwargs(device)): the same bytes; not both at once."""
    import torch

    from tetweave_codec.options import EncodeOptions

    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 32))
    opts = EncodeOptions(points=1024, sh_degree="0", quality="fast", iters=20, device="cpu", position_bits=8.5)
    a = encode(v, f, options=opts)
    b = encode(v, f, **opts.encoder_kwargs(torch.device("cpu")))
    assert a.data == b.data and a.stats["chamfer"] == b.stats["chamfer"]
    with pytest.raises(TypeError, match="either options or points"):
        encode(v, f, options=opts, points=2048)
