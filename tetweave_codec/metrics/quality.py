"""Triangle quality (per face of the decoded mesh; the reports give percentages of faces).

- aspect ratio AR = longest edge / shortest altitude = l_max² / (2·area) (paper Appendix C; 2/√3 ≈ 1.155 for
  an equilateral triangle, 2 for a right isosceles one, ∞ for a degenerate one); ``aspect_ratio_gt4_pct`` = %
  AR > 4.
- radius ratio RR = circumradius / inradius = (l_0 l_1 l_2 · s) / (4·area²) with s the half perimeter (2 for
  an equilateral triangle, 1 + √2 for a right isosceles one, ∞ for a degenerate one). The paper's text says
  "inradius to circumradius", but its "lower is better, > 4 is bad" only makes sense for this, the inverse,
  ratio. ``radius_ratio_gt4_pct`` = % RR > 4.
- ``small_angle_lt10_pct`` = % triangles whose smallest interior angle is < 10° (degenerate triangles count).
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.geometry.triangles import face_areas
from tetweave_codec.metrics.common import as_mesh


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """Per-face quality measures (see the module docstring for definitions).

    Returns {"aspect_ratio": (F,), "radius_ratio": (F,), "min_angle_deg": (F,)}; AR and RR are inf on
    degenerate (zero-area) faces, whose smallest angle is 0.
    """
    v, f = as_mesh(vertices, faces)
    tri = v[f]
    edges = np.stack([tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2], tri[:, 1] - tri[:, 0]], axis=1)  # opposite vi
    lengths = np.linalg.norm(edges, axis=2)
    area = face_areas(v, f)
    degenerate = ~(area > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        aspect = lengths.max(axis=1) ** 2 / (2.0 * area)
        half_perimeter = 0.5 * lengths.sum(axis=1)
        radius = lengths.prod(axis=1) * half_perimeter / (4.0 * area**2)
    aspect[degenerate] = np.inf
    radius[degenerate] = np.inf
    # angle at vertex i between the two edges leaving it; atan2 stays accurate for needles and caps alike
    angles = []
    for i in range(3):
        e1 = tri[:, (i + 1) % 3] - tri[:, i]
        e2 = tri[:, (i + 2) % 3] - tri[:, i]
        angles.append(np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.einsum("nd,nd->n", e1, e2)))
    min_angle = np.degrees(np.min(angles, axis=0))
    min_angle[degenerate] = 0.0
    return {"aspect_ratio": aspect, "radius_ratio": radius, "min_angle_deg": min_angle}
