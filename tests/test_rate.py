"""fit/rate.py: the late stage's estimate of the s stream's bits, against the container's own predictor."""

from __future__ import annotations

import numpy as np
import torch

from tetweave_codec.fit.rate import FILE_BITS_PER_POINT, SRate
from tetweave_codec.formats import predict
from tetweave_codec.formats import quantize as Q


def _cells_and_symbols(n=400, seed=0):
    rng = np.random.default_rng(seed)
    cells, _ = Q.merge_collisions(rng.integers(0, 256, size=(n, 3)))
    # a signed distance to a sphere in steps, plus noise: a plane through neighbours predicts most of it
    s = np.linalg.norm(cells - 128.0, axis=1) - 80.0 + rng.normal(0.0, 3.0, len(cells))
    return cells, np.floor(s).astype(np.int64)


def test_residuals_are_the_decoders_up_to_its_rounding():
    """For quantized s = (k + 1/2) step the estimate's residual is k + 1/2 - a with a the decoder's prediction
    sum, so the decoder's k - floor(a) differs from it by frac(a) - 1/2: within half a step."""
    cells, k = _cells_and_symbols()
    step = 1e-3
    rate = SRate(cells, step, torch.device("cpu"))
    s = torch.as_tensor(Q.dequantize_s(k, step), dtype=torch.float64)
    rate.beta = rate.beta.double()
    r = rate.residuals(s).numpy()
    exact = predict.residuals(cells, k)
    gap = exact - r
    assert gap.min() >= -0.5 - 1e-4 and gap.max() < 0.5 + 1e-4  # beta is float32
    assert np.abs(exact).mean() < 0.5 * np.abs(k).mean()  # the predictor works on this field


def test_bits_follow_log2_of_the_residuals_and_are_zero_at_zero():
    cells, k = _cells_and_symbols()
    rate = SRate(cells, 1.0, torch.device("cpu"))
    rate.beta = rate.beta.double()
    s = torch.as_tensor(k + 0.5, dtype=torch.float64)
    r = rate.residuals(s)
    expected = np.log2(1 + np.sqrt(r.numpy() ** 2 + 0.25)) - np.log2(1.5)
    assert np.isclose(float(rate.bits(s)), expected.sum())
    # s on a plane costs almost nothing: the predictor reproduces it up to its ridge on the gradient
    plane = torch.as_tensor(cells @ np.array([0.3, -0.2, 0.1]), dtype=torch.float64)
    interior = np.flatnonzero((predict.causal_neighbors(cells)[0] >= 0).sum(1) >= 4)
    assert float(rate.residuals(plane)[interior].abs().max()) < 0.1


def test_bits_gradient_matches_finite_differences():
    cells, k = _cells_and_symbols(120, seed=3)
    rate = SRate(cells, 0.5, torch.device("cpu"))
    rate.beta = rate.beta.double()
    s = torch.as_tensor(Q.dequantize_s(k, 0.5), dtype=torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(rate.bits, (s,), eps=1e-6, atol=1e-5)


def test_weight_is_the_slope_of_the_loss_per_bit():
    cells, _ = _cells_and_symbols()
    rate = SRate(cells, 1.0, torch.device("cpu"))
    assert np.isclose(rate.weight(0.3, 0.8), 0.8 * 0.3 / (FILE_BITS_PER_POINT * len(cells)))
    assert rate.weight(-1.0, 1.0) == 0.0
