"""One row of `tetweave bench`: its columns, and one method on one mesh (encode, decode, time, measure).

A row is a plain dict with the keys of `COLUMNS` (`empty_row`): one per (mesh, method, setting), plus one "input"
row per mesh (`input_row`: raw size and the input's own triangle quality and topology). `encode_method` and
`measure_method` fill it (`run_method`: both, and the self-check of a tetweave row); a failure of one method on one
mesh (an exception anywhere in encode, decode or the metrics) is recorded in the row's ``error`` column
(`error_text`). `MeshResult` holds one mesh's rows, decoded meshes and tetweave files. The batch (batch.py: every
method) and the adaptive sweep (sweep.py: the classical settings that decide the verdict) both make rows here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tetweave_codec.bench.methods import TETWEAVE, Method
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.triangles import sample_surface
from tetweave_codec.metrics.common import MetricOptions, as_mesh
from tetweave_codec.metrics.fidelity import Reference, point_surface_distance, to_frame
from tetweave_codec.metrics.summary import evaluate, mesh_report

# Result columns in CSV order. Distances are in the input's normalized frame (see tetweave_codec.metrics.fidelity).
ID_COLUMNS = ["mesh", "family", "curve", "setting"]
PARAM_COLUMNS = [
    "quantization_bits",
    "keep_fraction",
    "points",
    "target_bytes",
    "sh_degree",
    "layout",
    "holes",
    "points_stored",
]
SIZE_COLUMNS = ["bytes", "bits_per_vertex", "encode_s", "decode_s", "metrics_s"]
FIDELITY_COLUMNS = [
    "chamfer",
    "hausdorff",
    "normal_consistency",
    "f1@0.001",
    "f1@0.005",
    "edge_chamfer",
    "edge_f1",
    "inaccurate_normals_pct",
]
QUALITY_COLUMNS = [
    "aspect_ratio_gt4_pct",
    "radius_ratio_gt4_pct",
    "small_angle_lt10_pct",
    "self_intersect_pct",
    "watertight",
    "two_manifold",
    "oriented",
    "manifold3d_ok",
    "boundary_edges",
    "nonmanifold_edges",
    "n_vertices",
    "n_faces",
]
# unseen_area_pct (tetweave rows): % of the decoded area no outside view sees, the encode summary's self-check
# (metrics.unseen); target: what the distances are measured against, "all" (the input's faces) or "visible"
# (`bench_target`)
COLUMNS = [
    *ID_COLUMNS,
    *PARAM_COLUMNS,
    *SIZE_COLUMNS,
    *FIDELITY_COLUMNS,
    *QUALITY_COLUMNS,
    "unseen_area_pct",
    "target",
    "error",
]

INPUT_FAMILY = "input"
ProgressFn = Callable[[str], None]


@dataclass
class MeshResult:
    """Everything measured on one input mesh.

    name: label of the mesh (file stem, made unique). vertices (V,3), faces (F,3): the input. rows: result
    rows (the input row first). decoded: method name -> decoded (vertices, faces), successes only. files:
    tetweave setting -> its `.tw` bytes, successes only (classical outputs are not kept). target: what the rows
    were measured against (`Target.describe`; empty when the input could not be measured).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    rows: list[dict] = field(default_factory=list)
    decoded: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    files: dict[str, bytes] = field(default_factory=dict)
    target: str = ""


def _referenced_vertices(faces: np.ndarray) -> int:
    used = np.zeros(int(faces.max()) + 1 if len(faces) else 0, dtype=bool)
    used[faces.reshape(-1)] = True
    return int(used.sum())


def empty_row(name: str, method: Method | None) -> dict:
    row = dict.fromkeys(COLUMNS, "")
    row["mesh"] = name
    if method is None:
        row.update(family=INPUT_FAMILY, curve=INPUT_FAMILY, setting="raw float32")
    else:
        row.update(family=method.family, curve=method.curve, setting=method.setting)
        row.update(method.params())
    return row


def error_text(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {text}"[:300]


def input_row(name: str, vertices: np.ndarray, faces: np.ndarray, options: MetricOptions) -> dict:
    """The reference row of an input: raw size (float32 xyz + uint32 indices) and its own quality."""
    row = empty_row(name, None)
    n_in = _referenced_vertices(faces)
    row["bytes"] = 12 * n_in + 12 * len(faces)
    row["bits_per_vertex"] = 8.0 * row["bytes"] / n_in
    t0 = time.perf_counter()
    report = mesh_report(vertices, faces, options)
    row["metrics_s"] = time.perf_counter() - t0
    row.update({k: v for k, v in report.items() if k in COLUMNS})
    return row


def encode_method(name: str, method: Method, vertices: np.ndarray, faces: np.ndarray) -> tuple[dict, bytes | None]:
    """Encode one mesh with one method: (its row with the size columns, the bytes; None and the row's error on
    failure)."""
    row = empty_row(name, method)
    try:
        t0 = time.perf_counter()
        data = method.encode(vertices, faces)
        row["encode_s"] = time.perf_counter() - t0 + method.reused_seconds()
        row["bytes"] = len(data)
        row["bits_per_vertex"] = 8.0 * len(data) / _referenced_vertices(faces)
        row.update(method.info(data))
        return row, data
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = error_text(exc)
        return row, None


def measure_method(
    row: dict, method: Method, data: bytes, reference: Reference, options: MetricOptions, chamfer_only: bool = False
) -> tuple[np.ndarray, np.ndarray] | None:
    """Decode `encode_method`'s bytes and fill `row` with the decoded mesh's metrics against the prepared input
    (all of them, or with `chamfer_only` the Chamfer distance and the counts: `reference_chamfer`, ~6x cheaper);
    returns the decoded mesh, None (and the row's error) on failure."""
    try:
        t0 = time.perf_counter()
        v_out, f_out = method.decode(data)
        row["decode_s"] = time.perf_counter() - t0
        row["n_vertices"], row["n_faces"] = _referenced_vertices(f_out), len(f_out)
        t0 = time.perf_counter()
        if chamfer_only:
            metrics = {"chamfer": reference_chamfer(reference, v_out, f_out, options)}
        else:
            metrics = evaluate(reference, v_out, f_out, options)
        row["metrics_s"] = time.perf_counter() - t0
        row.update({k: v for k, v in metrics.items() if k in COLUMNS})
        return v_out, f_out
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = error_text(exc)
        return None


def reference_chamfer(reference: Reference, vertices: np.ndarray, faces: np.ndarray, options: MetricOptions) -> float:
    """The `chamfer` of `summary.evaluate` (the same samples, hence the same value) without the other metrics: the
    input's samples and tree come prepared, the decoded mesh (vertices (V,3) in the input's frame, faces (F,3)) is
    sampled and its tree built. ValueError on a mesh without faces."""
    v, f = as_mesh(to_frame(vertices, reference.scale, reference.offset), faces)
    if len(f) == 0:
        raise ValueError("the decoded mesh has no faces")
    points, _ = sample_surface(v, f, options.n_samples, options.seed)
    to_decoded, _ = SurfaceTree(v, f).query(reference.mesh.points)[:2]
    to_input, _ = point_surface_distance(points, reference.mesh)
    return float(0.5 * (np.sqrt(np.maximum(to_decoded, 0.0)).mean() + to_input.mean()))


def run_method(
    name: str, method: Method, vertices: np.ndarray, faces: np.ndarray, reference, options: MetricOptions
) -> tuple[dict, tuple[np.ndarray, np.ndarray] | None, bytes | None]:
    """Encode, decode and measure one method on one mesh; returns (row, decoded mesh, encoded bytes), the last
    two None on failure."""
    row, data = encode_method(name, method, vertices, faces)
    decoded = None if data is None else measure_method(row, method, data, reference, options)
    if decoded is not None and method.family == TETWEAVE:
        _self_check(row, *decoded)
    return row, decoded, (None if decoded is None else data)


def _self_check(row: dict, vertices: np.ndarray, faces: np.ndarray) -> None:
    """The encode summary's self-check of a decoded tetweave mesh into `row`: unseen_area_pct (metrics.unseen;
    left empty when not measured), its time added to metrics_s."""
    from tetweave_codec.metrics.unseen import self_check

    try:
        check = self_check(vertices, faces)
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = error_text(exc)
        return
    if check is not None:
        row["unseen_area_pct"] = 100.0 * check.share
        row["metrics_s"] = (row.get("metrics_s") or 0.0) + check.seconds


def say_row(say: ProgressFn, name: str, label: str, row: dict) -> None:
    """One progress line for a measured row (or its failure)."""
    if row.get("error"):
        say(f"{name}: {label}: FAILED: {row['error']}")
        return
    say(
        f"{name}: {label}: {row['bytes']:,} bytes, CD {row['chamfer']:.3g}, {row['n_faces']:,} faces "
        f"(encode {row['encode_s']:.2f}s, decode {row['decode_s']:.2f}s, metrics {row['metrics_s']:.1f}s)"
    )
