"""A differentiable estimate of the s stream's bits, for the late stage: s chosen for the predictor as well as the
surface.

The container codes s as residuals against a plane fitted through the 8 nearest earlier points
(formats/predict.py). Those residuals cost ~6-7 bits per point on fitted files because a fitted s is only
roughly planar, and the surface does not need it to be otherwise: a vertex lies where s changes sign along an
active edge, at the ratio s_i / (s_i - s_j), so the s of a point whose edges barely move the surface, or a
common scale of both ends of an edge, is free. The late stage minimizes the geometric loss plus

    lambda * sum_i bits(r_i),   r_i = u_i - sum_j beta_ij u_j,   u = s / step,

with beta (N,8) the decoder's predictor weights (positions only, so fixed during the late stage) and
bits(r) = log2(1 + sqrt(r^2 + 1/4)) - log2(1.5), a smooth stand-in for the code length of a residual, which grows
with log2 |r| (its bucket, plus the raw bits below the leading one; formats/README.md "s section, predicted").
u is computed from the quantized s the forward pass sees (straight through), so r is the residual of the symbols
the file will hold up to the predictor's rounding: for u = k + 1/2 the decoder's residual k - floor(sum beta u) is
r - 1/2 + frac(sum beta u), within half a step of r.

lambda is the rate-distortion slope in loss units per bit: at the operating point of a fit the Chamfer distance
D falls with the file's bits R about as D ~ R^-alpha, so one bit is worth alpha * D / R of distance; with the
loss's Chamfer part L = weights.surface * D, lambda = kappa * L / (FILE_BITS_PER_POINT * N), kappa standing for
alpha (FitConfig.s_rate; 0 = off).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

# Bits per point of a whole v2 file at the fit's defaults (positions ~9.7, s ~6.7, c ~0.1 on the shared meshes'
# 5-40 KB files): R = FILE_BITS_PER_POINT * N in the slope above.
FILE_BITS_PER_POINT = 16.5
_HALF_SQ = 0.25  # smoothing of |r| at 0 (in steps): the code length is flat below one step
_BITS_AT_ZERO = math.log2(1.5)


class SRate:
    """The s stream's bit estimate on fixed grid cells (N,3) in canonical order, for s steps of `step`.

    idx (N,8) long (-1 = none, read as point 0 with weight 0) and beta (N,8) are the decoder's neighbours and
    predictor weights (formats.predict), on `device`.
    """

    def __init__(self, cells: np.ndarray, step: float, device: torch.device):
        from tetweave_codec.formats import predict

        idx, d2 = predict.causal_neighbors(np.asarray(cells, dtype=np.int64))
        beta = predict.predictor_weights(cells, idx, d2)
        self.n = len(idx)
        self.step = float(step)
        self.idx = torch.as_tensor(np.maximum(idx, 0), dtype=torch.long, device=device)
        self.beta = torch.as_tensor(np.where(idx >= 0, beta, 0.0), dtype=torch.float32, device=device)

    def residuals(self, s: Tensor) -> Tensor:
        """Residuals (N,) in steps of the s values (N,) (the decoder's within half a step, see module docstring)."""
        u = s / self.step
        return u - (self.beta * u[self.idx]).sum(dim=1)

    def bits(self, s: Tensor) -> Tensor:
        """Estimated bits (scalar tensor) of the s stream for the s values (N,)."""
        r = self.residuals(s)
        return (torch.log2(1.0 + torch.sqrt(r * r + _HALF_SQ)) - _BITS_AT_ZERO).sum()

    def weight(self, chamfer_loss: float, kappa: float) -> float:
        """lambda (loss units per bit) for the current Chamfer part of the loss (see module docstring)."""
        return kappa * max(chamfer_loss, 0.0) / (FILE_BITS_PER_POINT * max(self.n, 1))
