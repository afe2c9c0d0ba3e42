"""Active and passive points of a TetWeave tetrahedral grid (paper section 3.2 and 4.3).

An edge is *active* when the base signed distances of its endpoints have opposite signs (s < 0 inside,
s >= 0 outside); *active points* are the endpoints of active edges. Because every pair of vertices of a tet
is an edge, the active points are exactly the vertices of tets with both signs. The *one-ring* of a point set
adds every point that shares a tet (equivalently an edge) with it; points outside the one-ring of the active
points are *passive*: they share no tet with the surface, and resampling may move or drop them.

All functions take numpy arrays or torch tensors (any device) and return the same kind.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def _zeros_bool(like: Any, n: int) -> Any:
    if type(like).__module__.startswith("torch"):
        import torch

        return torch.zeros(n, dtype=torch.bool, device=like.device)
    return np.zeros(n, dtype=bool)


def mixed_tets(tets: Any, s: Any) -> Any:
    """Tets with vertices on both sides. tets (T, 4), s (N,) -> bool (T,)."""
    count = (s < 0)[tets].sum(1)
    return (count > 0) & (count < 4)


def active_mask(tets: Any, s: Any) -> Any:
    """Active points: endpoints of edges whose base s changes sign.

    Args:
        tets: (T, 4) integer indices.
        s: (N,) base signed distance.
    Returns:
        (N,) bool.
    """
    mask = _zeros_bool(s, s.shape[0])
    mask[tets[mixed_tets(tets, s)].reshape(-1)] = True
    return mask


def one_ring_mask(tets: Any, mask: Any) -> Any:
    """Points in `mask` plus every point sharing a tet (an edge) with one of them.

    Args:
        tets: (T, 4) integer indices.
        mask: (N,) bool.
    Returns:
        (N,) bool, a superset of `mask`.
    """
    ring = mask.clone() if hasattr(mask, "clone") else mask.copy()
    ring[tets[mask[tets].any(1)].reshape(-1)] = True
    return ring


def passive_mask(tets: Any, s: Any) -> Any:
    """Passive points: not in the one-ring of any active point (includes points in no tet). (N,) bool."""
    return ~one_ring_mask(tets, active_mask(tets, s))
