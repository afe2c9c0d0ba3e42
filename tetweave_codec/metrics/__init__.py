"""Metrics of decoded meshes, one module per concept.

* `common`: `MetricOptions` (sample counts, thresholds) and the mesh-array helpers.
* `fidelity`: a decoded mesh against its input, in the input's normalized frame: point-to-surface Chamfer and
  Hausdorff distances, normal consistency, F1, edge Chamfer / edge F1 (`chamfer_distance`, `prepare_reference`,
  `fidelity`).
* `quality`: triangle quality (aspect ratio, radius ratio, smallest angle).
* `manifold`: topology (watertight, 2-manifold, oriented, boundary and non-manifold edges, manifold3d's verdict).
* `intersections`: self-intersecting faces.
* `summary`: all of the above as one row (`mesh_report`, `evaluate`).
* `rate_distortion`: Pareto fronts and sizes at a matched error (the benchmark's verdict).
* `unseen`: the share of a mesh's area no outside view sees (`unseen_area_share`), the encoder's self-check of its
  decoded mesh (`self_check`; renders through fit.visible, torch at call time).

Surface samples and face normals come from `tetweave_codec.geometry.triangles`. `chamfer_distance` and `topology`
are also importable from the package itself (the encoder's summary uses the first).
"""

from __future__ import annotations

from tetweave_codec.metrics.fidelity import chamfer_distance
from tetweave_codec.metrics.manifold import topology

__all__ = ["chamfer_distance", "topology"]
