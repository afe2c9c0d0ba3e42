"""Real spherical harmonics of degrees 0..3, the basis of TetWeave's directional signed distance.

Convention (documented here because the `.tw` container stores coefficients in this basis):

* Directions are unit vectors ``d = (x, y, z)``; with polar angle ``theta`` measured from +z and azimuth
  ``phi`` from +x towards +y, ``x = sin(theta) cos(phi)``, ``y = sin(theta) sin(phi)``, ``z = cos(theta)``.
* For TetWeave's directional distance (paper eq. 1) the SH of point ``i`` is evaluated at the direction of the
  edge *away from* ``i``: ``dir(i -> j) = (p_j - p_i) / |p_j - p_i|``, i.e. the polar and azimuthal angle of
  ``p_j - p_i``. (The authors' reference code evaluates at ``p_i - p_j``; a coefficient set converts between
  the two by negating its odd-degree coefficients, see `sh_parity`.)
* Basis: real, orthonormal on the unit sphere (``integral Y_a Y_b dOmega = delta_ab``), *without* the
  Condon-Shortley phase, ordered by degree ``l`` then order ``m = -l..l``; coefficient index ``l*l + l + m``.
  Written as homogeneous polynomials of the unit direction:

  ====  ====  =============================================  ==========================
  idx   (l,m) function                                       constant
  ====  ====  =============================================  ==========================
  0     0, 0  SH_C0                                          1/(2 sqrt(pi))
  1     1,-1  SH_C1 * y                                      sqrt(3/(4 pi))
  2     1, 0  SH_C1 * z
  3     1, 1  SH_C1 * x
  4     2,-2  SH_C2[0] * x y                                 sqrt(15/pi)/2
  5     2,-1  SH_C2[0] * y z
  6     2, 0  SH_C2[1] * (2 z^2 - x^2 - y^2)                 sqrt(5/pi)/4
  7     2, 1  SH_C2[0] * x z
  8     2, 2  SH_C2[2] * (x^2 - y^2)                         sqrt(15/pi)/4
  9     3,-3  SH_C3[0] * y (3 x^2 - y^2)                     sqrt(35/(2 pi))/4
  10    3,-2  SH_C3[1] * x y z                               sqrt(105/pi)/2
  11    3,-1  SH_C3[2] * y (4 z^2 - x^2 - y^2)               sqrt(21/(2 pi))/4
  12    3, 0  SH_C3[3] * z (2 z^2 - 3 x^2 - 3 y^2)           sqrt(7/pi)/4
  13    3, 1  SH_C3[2] * x (4 z^2 - x^2 - y^2)
  14    3, 2  SH_C3[4] * z (x^2 - y^2)                       sqrt(105/pi)/4
  15    3, 3  SH_C3[0] * x (x^2 - 3 y^2)
  ====  ====  =============================================  ==========================

Degree ``-1`` means "no spherical harmonics" (zero coefficients per point); ``num_coeffs(-1) == 0``.

All functions accept torch tensors (differentiable) or numpy arrays and return the same kind. They only use
elementwise arithmetic (no BLAS), so the numpy path is deterministic for the decoder.
"""

from __future__ import annotations

from typing import Any

import numpy as np

SH_DEGREE_MAX = 3
SH_DEGREE_NONE = -1

SH_C0 = 0.28209479177387814  # 1 / (2 sqrt(pi))
SH_C1 = 0.4886025119029199  # sqrt(3 / (4 pi))
SH_C2 = (
    1.0925484305920792,  # sqrt(15 / pi) / 2
    0.31539156525252005,  # sqrt(5 / pi) / 4
    0.5462742152960396,  # sqrt(15 / pi) / 4
)
SH_C3 = (
    0.5900435899266435,  # sqrt(35 / (2 pi)) / 4
    2.890611442640554,  # sqrt(105 / pi) / 2
    0.4570457994644658,  # sqrt(21 / (2 pi)) / 4
    0.3731763325901154,  # sqrt(7 / pi) / 4
    1.445305721320277,  # sqrt(105 / pi) / 4
)


def num_coeffs(degree: int) -> int:
    """Number of SH coefficients per point for `degree` (-1..3): ``(degree + 1) ** 2`` (0 for -1)."""
    check_degree(degree)
    return (degree + 1) ** 2


def check_degree(degree: int) -> int:
    """Return `degree` if it is a supported SH degree (-1 = none, 0..3), else raise ValueError."""
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)):
        raise ValueError(f"SH degree must be an integer, got {degree!r}")
    if not SH_DEGREE_NONE <= int(degree) <= SH_DEGREE_MAX:
        raise ValueError(f"SH degree must be in {SH_DEGREE_NONE}..{SH_DEGREE_MAX}, got {degree}")
    return int(degree)


def degree_from_num_coeffs(q: int) -> int:
    """Inverse of `num_coeffs`: the degree whose basis has `q` coefficients (0 -> -1), else ValueError."""
    for degree in range(SH_DEGREE_NONE, SH_DEGREE_MAX + 1):
        if num_coeffs(degree) == q:
            return degree
    raise ValueError(f"{q} SH coefficients per point is not (degree + 1)^2 for a degree -1..{SH_DEGREE_MAX}")


def sh_parity(degree: int) -> np.ndarray:
    """Signs ``(-1) ** l`` per coefficient, (q,) float64: ``sh_basis(-d) == sh_parity * sh_basis(d)``."""
    check_degree(degree)
    return np.array([(-1.0) ** l for l in range(degree + 1) for _ in range(2 * l + 1)], dtype=np.float64)


def _is_torch(a: Any) -> bool:
    return type(a).__module__.startswith("torch")


def sh_basis_terms(dirs: Any, degree: int) -> list:
    """The q basis functions at unit directions as a list of (...,) arrays (see `sh_basis`)."""
    num_coeffs(degree)
    if degree < 0:
        return []
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    if _is_torch(dirs):
        import torch

        terms = [torch.full_like(x, SH_C0)]
    else:
        terms = [np.full_like(x, SH_C0)]
    if degree >= 1:
        terms += [SH_C1 * y, SH_C1 * z, SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        terms += [
            SH_C2[0] * (x * y),
            SH_C2[0] * (y * z),
            SH_C2[1] * (2.0 * zz - xx - yy),
            SH_C2[0] * (x * z),
            SH_C2[2] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * (x * y * z),
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[2] * x * (4.0 * zz - xx - yy),
            SH_C3[4] * z * (xx - yy),
            SH_C3[0] * x * (xx - 3.0 * yy),
        ]
    return terms


def sh_basis(dirs: Any, degree: int) -> Any:
    """Real SH basis at unit directions.

    Args:
        dirs: (..., 3) unit vectors, torch tensor or numpy array.
        degree: -1..3.
    Returns:
        (..., q) basis values, q = num_coeffs(degree), same array kind and dtype as `dirs`.
    """
    terms = sh_basis_terms(dirs, degree)
    if _is_torch(dirs):
        import torch

        return torch.stack(terms, -1) if terms else dirs.new_zeros(dirs.shape[:-1] + (0,))
    return np.stack(terms, -1) if terms else np.zeros(dirs.shape[:-1] + (0,), dtype=dirs.dtype)


def sh_eval(dirs: Any, coeffs: Any) -> Any:
    """Evaluate SH functions: ``sum_k coeffs[..., k] * Y_k(dirs)``.

    Args:
        dirs: (..., 3) unit vectors.
        coeffs: (..., q) coefficients (q a perfect square, 0 allowed), same array kind as `dirs`.
    Returns:
        (...,) values, accumulated in coefficient order (zeros when q == 0).
    """
    degree = degree_from_num_coeffs(int(coeffs.shape[-1]))
    value = dirs[..., 0] * 0
    for k, term in enumerate(sh_basis_terms(dirs, degree)):
        value = value + term * coeffs[..., k]
    return value
