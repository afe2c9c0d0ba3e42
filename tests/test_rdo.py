"""RD-optimized s symbols (fit/rdo.py): signs kept, deterministic, fewer bytes at equal error, exact decoding."""

from __future__ import annotations

import numpy as np
import pytest

from tetweave_codec.decoder import decode
from tetweave_codec.fit import rdo as R
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.common import FLAG_S_PREDICTED
from tetweave_codec.formats.tw import TetWeaveFileV2, backend_flags, pack_v2
from tetweave_codec.geometry.delaunay import resolve_backend
from tetweave_codec.metrics import chamfer_distance

manifold3d = pytest.importorskip("manifold3d")
pytest.importorskip("igl")

RADIUS = 0.6
BITS = 6
S_STEP = 0.002


def _sphere_case(noise: float = 0.004, seed: int = 0):
    """Grid points in a shell around a sphere, latent s = signed distance + noise (a fit's wobble)."""
    mesh = manifold3d.Manifold.sphere(RADIUS, 64).to_mesh()
    v = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    n = 1 << BITS
    axis = Q.dequantize_positions(np.arange(n)[:, None].repeat(3, 1), BITS)[:, 0]
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    grid = grid[np.abs(np.linalg.norm(grid, axis=1) - RADIUS) < 0.08]
    cells, _ = Q.merge_collisions(Q.quantize_positions(grid, BITS))
    points = Q.dequantize_positions(cells, BITS)
    rng = np.random.default_rng(seed)
    s = np.linalg.norm(points, axis=1) - RADIUS + noise * rng.standard_normal(len(points))
    return v, f, cells, points, s


def _file(cells, s_sym, backend) -> bytes:
    flags = backend_flags(backend) | FLAG_S_PREDICTED
    f = TetWeaveFileV2(cells, s_sym, np.zeros((len(cells), 0), np.int64), BITS, S_STEP, (), -1, 1.0,
                       np.zeros(3), flags)  # fmt: skip
    return pack_v2(f)


def _rdo_symbols(cells, points, s, backend, lambda_scale=R.LAMBDA_SCALE):
    rdo = R.prepare(points, cells, backend)
    rdo.lambda_scale = lambda_scale
    plain = Q.quantize_s(s, S_STEP)
    return plain, R.optimize_s_symbols(rdo, plain, S_STEP, np.zeros((len(s), 0)))


def test_rdo_lowers_bytes_at_equal_error_and_keeps_signs():
    v, f, cells, points, s = _sphere_case()
    backend = resolve_backend("auto")
    plain, chosen = _rdo_symbols(cells, points, s, backend)
    np.testing.assert_array_equal(chosen < 0, plain < 0)
    assert np.abs(chosen - plain).max() <= R.WINDOW
    assert (chosen != plain).mean() > 0.05  # it does something
    sizes, errors = [], []
    for sym in (plain, chosen):
        data = _file(cells, sym, backend)
        out_v, out_f = decode(data)
        sizes.append(len(data))
        errors.append(chamfer_distance(v, f, out_v, out_f, n_samples=50_000, seed=0, normalize=False))
    assert sizes[1] < 0.95 * sizes[0], sizes
    assert errors[1] <= 1.02 * errors[0], errors


def test_rdo_is_deterministic_and_zero_lambda_costs_no_error():
    v, f, cells, points, s = _sphere_case(seed=1)
    backend = resolve_backend("auto")
    a = _rdo_symbols(cells, points, s, backend)[1]
    b = _rdo_symbols(cells, points, s, backend)[1]
    np.testing.assert_array_equal(a, b)
    # lambda 0: bits are free, the plain symbols (no displacement) are optimal and kept
    rdo = R.prepare(points, cells, backend)
    rdo.lambda_scale = 0.0
    plain = Q.quantize_s(s, S_STEP)
    np.testing.assert_array_equal(R.optimize_s_symbols(rdo, plain, S_STEP, np.zeros((len(s), 0))), plain)
    table = R.distortion_table(rdo, plain, S_STEP, np.zeros((len(s), 0)))
    assert (table[:, R.WINDOW] == 0).all() and (table >= 0).all()


def test_residual_pricing_matches_the_format():
    from tetweave_codec.formats import predict

    _, _, cells, _, s = _sphere_case()
    sym = Q.quantize_s(s, S_STEP)
    nbr, d2 = predict.causal_neighbors(cells)
    beta = predict.predictor_weights(cells, nbr, d2)
    np.testing.assert_array_equal(R.residuals(nbr, beta, sym), predict.residuals(cells, sym))


def test_encoder_runs_rdo_and_decodes_exactly_what_it_reported(monkeypatch):
    import dataclasses

    from tetweave_codec.encoder import Job, encode

    plain_config = Job.config
    monkeypatch.setattr(Job, "config", lambda self, *a: dataclasses.replace(plain_config(self, *a), s_rdo=True))

    mesh = manifold3d.Manifold.sphere(1.0, 32).to_mesh()
    v = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    options = {"points": 1500, "quality": "fast", "iters": 30, "device": "cpu", "seed": 0}
    a, b = encode(v, f, **options), encode(v, f, **options)
    assert "rdo" in a.stats["seconds"]
    assert a.data == b.data
    out_v, out_f = decode(a.data)
    np.testing.assert_array_equal(out_v, a.vertices)
    np.testing.assert_array_equal(out_f, a.faces)
